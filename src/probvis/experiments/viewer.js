// Interactive comparison of a probvis experiment report: two images (a method or the reference) split by a
// slider, with exposure, a false-colour relative-error view and a signed view, zoom (wheel) and pan (drag).
// Float images come from data/*.js as base64 float16 (window.PROBVIS_DATA); no network access.
"use strict";

(function () {
  function halfToFloat(h) {
    const s = h & 0x8000 ? -1 : 1, e = (h >> 10) & 0x1f, f = h & 0x3ff;
    if (e === 0) return s * Math.pow(2, -14) * (f / 1024);
    if (e === 31) return f ? NaN : s * Infinity;
    return s * Math.pow(2, e - 15) * (1 + f / 1024);
  }

  function decode(b64) {
    const bin = atob(b64), n = bin.length >> 1, out = new Float32Array(n);
    for (let i = 0; i < n; i++) out[i] = halfToFloat(bin.charCodeAt(2 * i) | (bin.charCodeAt(2 * i + 1) << 8));
    return out;
  }

  function srgb(x) {
    x = Math.min(1, Math.max(0, x));
    return 255 * (x <= 0.0031308 ? 12.92 * x : 1.055 * Math.pow(x, 1 / 2.4) - 0.055);
  }

  // Piecewise-linear false-colour ramp: black, blue, magenta, orange, yellow, white.
  const RAMP = [[0, 0, 0], [30, 40, 160], [170, 40, 160], [240, 120, 30], [250, 230, 60], [255, 255, 255]];
  function ramp(t) {
    t = Math.min(1, Math.max(0, t)) * (RAMP.length - 1);
    const i = Math.min(RAMP.length - 2, Math.floor(t)), f = t - i, a = RAMP[i], b = RAMP[i + 1];
    return [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2])];
  }

  function el(tag, attrs, parent) {
    const e = document.createElement(tag);
    for (const k in attrs) {
      if (k === "text") e.textContent = attrs[k]; else e.setAttribute(k, attrs[k]);
    }
    if (parent) parent.appendChild(e);
    return e;
  }

  function select(parent, label, options, value) {
    const wrap = el("label", {text: label + " "}, parent);
    const s = el("select", {}, wrap);
    for (const [v, t] of options) el("option", {value: v, text: t}, s);
    s.value = value;
    return s;
  }

  function Viewer(root, data) {
    const d = data, w = d.width, h = d.height, cache = {};
    const image = (key) => cache[key] || (cache[key] = d.images[key] ? decode(d.images[key]) : null);
    const controls = el("div", {class: "controls"}, root);
    const sources = [["reference", "reference"]].concat(d.methods.map((m) => [m, m]));
    const rays = select(controls, "shadow rays", d.shadowRays.map((r) => [String(r), String(r)]),
                        String(d.shadowRays[Math.min(2, d.shadowRays.length - 1)]));
    const left = select(controls, "left", sources, d.methods[0]);
    const right = select(controls, "right", sources, d.methods.length > 1 ? d.methods[1] : "reference");
    const mode = select(controls, "view", [["image", "image"], ["error", "relative error (false colour)"],
                                           ["signed", "signed (negative in red)"]], "image");
    const expWrap = el("label", {text: "exposure "}, controls);
    const exposure = el("input", {type: "range", min: "-6", max: "6", step: "0.25", value: "0", class: "exposure"},
                        expWrap);
    const splitWrap = el("label", {text: "split "}, controls);
    const split = el("input", {type: "range", min: "0", max: "100", step: "1", value: "50", class: "split"},
                     splitWrap);
    const reset = el("button", {type: "button", text: "reset zoom"}, controls);
    const stage = el("div", {class: "stage"}, root);
    const canvas = el("canvas", {width: String(w), height: String(h)}, stage);
    const status = el("div", {class: "status", text: " "}, root);
    const legend = el("div", {class: "legend"}, root);
    const ctx = canvas.getContext("2d", {willReadFrequently: true});  // CPU canvas: every draw is a putImageData
    let zoom = 1, panX = 0, panY = 0;

    function fit() {  // the whole image, as large as the panel allows, centred
      const sw = stage.clientWidth || 512, sh = stage.clientHeight || 512;
      zoom = Math.min(sw / w, sh / h);
      panX = (sw - w * zoom) / 2;
      panY = (sh - h * zoom) / 2;
    }

    function key(src) {
      return src === "reference" ? "reference" : src + "@" + rays.value;
    }

    function pixel(img, ref, i, m, scale) {
      const r = img[3 * i], g = img[3 * i + 1], b = img[3 * i + 2];
      if (m === "image") return [srgb(r * scale), srgb(g * scale), srgb(b * scale)];
      if (m === "error") {
        let e = 0;
        for (let c = 0; c < 3; c++) e += Math.abs(img[3 * i + c] - ref[3 * i + c]) / (Math.abs(ref[3 * i + c]) + 0.1);
        return ramp((e / 3) * scale);
      }
      const y = (0.2126 * r + 0.7152 * g + 0.0722 * b) * scale;
      return y < 0 ? [srgb(-y), 0, 0] : [srgb(y), srgb(y), srgb(y)];
    }

    function draw() {
      const a = image(key(left.value)), b = image(key(right.value)), ref = image("reference");
      const out = ctx.createImageData(w, h), m = mode.value, scale = Math.pow(2, Number(exposure.value));
      const cut = Math.round((Number(split.value) / 100) * w);
      for (let y = 0; y < h; y++) {
        for (let x = 0; x < w; x++) {
          const i = y * w + x, src = x < cut ? a : b, o = 4 * i;
          const p = src ? pixel(src, ref, i, m, scale) : [80, 0, 80];
          out.data[o] = p[0]; out.data[o + 1] = p[1]; out.data[o + 2] = p[2]; out.data[o + 3] = 255;
          if (x === cut && cut > 0 && cut < w) { out.data[o] = 255; out.data[o + 1] = 255; out.data[o + 2] = 255; }
        }
      }
      ctx.putImageData(out, 0, 0);
      canvas.dataset.current = [left.value, right.value, rays.value, m].join("|");
      legend.textContent = m === "image" ? "" : m === "error"
        ? "false colour: |x − ref| / (|ref| + 0.1), black = 0, white ≥ " + (1 / scale).toPrecision(3)
        : "luminance; pixels with a negative estimate are red";
      place();
    }

    function place() {
      canvas.style.transform = "translate(" + panX + "px," + panY + "px) scale(" + zoom + ")";
    }

    for (const c of [rays, left, right, mode, exposure, split]) c.addEventListener("input", draw);
    reset.addEventListener("click", () => { fit(); place(); });
    window.addEventListener("resize", () => { fit(); place(); });
    stage.addEventListener("wheel", (ev) => {
      ev.preventDefault();
      const r = stage.getBoundingClientRect(), mx = ev.clientX - r.left, my = ev.clientY - r.top;
      const f = ev.deltaY < 0 ? 1.25 : 0.8, nz = Math.min(64, Math.max(0.25, zoom * f));
      panX = mx - ((mx - panX) * nz) / zoom; panY = my - ((my - panY) * nz) / zoom; zoom = nz; place();
    }, {passive: false});
    let drag = null;
    stage.addEventListener("pointerdown", (ev) => { drag = [ev.clientX - panX, ev.clientY - panY]; });
    window.addEventListener("pointerup", () => { drag = null; });
    stage.addEventListener("pointermove", (ev) => {
      if (drag) { panX = ev.clientX - drag[0]; panY = ev.clientY - drag[1]; place(); }
      const r = canvas.getBoundingClientRect();
      const x = Math.floor(((ev.clientX - r.left) / r.width) * w), y = Math.floor(((ev.clientY - r.top) / r.height) * h);
      if (x < 0 || y < 0 || x >= w || y >= h) return;
      const show = (name) => {
        const img = image(key(name)), i = 3 * (y * w + x);
        return img ? name + " (" + [img[i], img[i + 1], img[i + 2]].map((v) => v.toFixed(4)).join(", ") + ")" : "";
      };
      status.textContent = "pixel " + x + ", " + y + ": " + show(left.value) + "  |  " + show(right.value);
    });
    fit();
    draw();
  }

  document.querySelectorAll(".viewer").forEach((root) => {
    const data = (window.PROBVIS_DATA || {})[root.dataset.scene];
    if (data) Viewer(root, data); else root.textContent = "no image data for this scene";
  });
})();
