"""Reader for the subset of Mitsuba 3's XML scene format that probvis renders.

Anything outside the subset raises `ProbvisError` naming the element, the file and the line.
"""
import functools
import os
import re
import warnings
import xml.sax
from dataclasses import dataclass, field
from pathlib import Path

import defusedxml.sax
import numpy as np

from ..errors import ProbvisError, missing_file
from ..io.linear_rgb import read_linear_rgb
from ..settings import (MAX_SHADOW_RAYS, MAX_SPP, RenderSettings, parse_float as _float,
                        parse_int as _int)
from . import shapes as shp
from . import transform as tf
from ..texture import BITMAP, CHECKERBOARD, WRAP_MODES, Texture
from .scene import EMITTER_ENVIRONMENT, MAX_COORDINATE, MAX_EMISSION, SceneBuilder
from .sensor import (FILTERS, FOV_AXES, FOV_ROUNDING, MAX_CUBIC_PARAMETER, MAX_FILM_EXTENT, MAX_FILM_SIDE,
                     MAX_FILTER_RADIUS, MAX_FOV, MIN_FILTER_REACH, Camera, camera_problem, tan_x_per_axis)
from .serialized import load_serialized
from .spectrum import spectrum_to_rgb

# Mitsuba's named indices of refraction (its `ior.h`) and conductor materials (its spectral data files)
_IORS = {"vacuum": 1.0, "helium": 1.00004, "hydrogen": 1.00013, "air": 1.00028, "carbon dioxide": 1.00045,
         "water": 1.3330, "acetone": 1.36, "ethanol": 1.361, "carbon tetrachloride": 1.461, "glycerol": 1.4729,
         "benzene": 1.501, "silicone oil": 1.52045, "bromine": 1.661, "water ice": 1.31, "fused quartz": 1.458,
         "pyrex": 1.470, "acrylic glass": 1.49, "polypropylene": 1.49, "bk7": 1.5046, "sodium chloride": 1.544,
         "amber": 1.55, "pet": 1.5750, "diamond": 2.419}
_CONDUCTORS = {"a-C", "Ag", "Al", "AlAs", "AlAs_palik", "AlSb", "AlSb_palik", "Au", "Be", "Be_palik", "Cr", "CsI",
               "CsI_palik", "Cu", "Cu_palik", "Cu2O", "Cu2O_palik", "CuO", "CuO_palik", "d-C", "d-C_palik", "Hg",
               "Hg_palik", "HgTe", "HgTe_palik", "Ir", "Ir_palik", "K", "K_palik", "Li", "Li_palik", "MgO",
               "MgO_palik", "Mo", "Mo_palik", "Na_palik", "Nb", "Nb_palik", "Ni_palik", "Rh", "Rh_palik", "Se",
               "Se_palik", "SiC", "SiC_palik", "SnTe", "SnTe_palik", "Ta", "Ta_palik", "Te", "Te_palik", "ThF4",
               "ThF4_palik", "TiC", "TiC_palik", "TiN", "TiN_palik", "TiO2", "TiO2_palik", "VC", "VC_palik", "V_palik",
               "VN", "VN_palik", "W", "W_palik", "none"}
MAX_NESTING = 64  # elements deep: real scenes nest a handful
MAX_TRANSFORM = 1e100  # a composed transform's entries: beyond, its products and inverse overflow
MIN_CUTOFF = 1e-3  # degrees: a spot's narrowest cone
MAX_UV_SCALE = 1e9  # a texture's to_uv entries
_APPROXIMATED_TEXTURES = ("mesh_attribute", "volume")  # Mitsuba 3's other textures
MAX_SCENE_BYTES = 256 << 20  # a scene file larger than this is not a scene (meshes live in their own files)


@dataclass
class Node:
    tag: str
    attrs: dict
    line: int
    children: list = field(default_factory=list)
    file: Path = None  # the file it was read from, where that is not the scene file itself (an <include>)
    order: int = 0  # its place in the document once includes are in place: what "defined after" compares


class _TreeBuilder(xml.sax.ContentHandler):
    def __init__(self):
        super().__init__()
        self.root = None
        self.stack = []

    def startElement(self, name, attrs):
        node = Node(name, dict(attrs), self._locator.getLineNumber())
        if len(self.stack) >= MAX_NESTING:
            raise ProbvisError(f"{node.line}: <{name}>: elements nested more than {MAX_NESTING} deep")
        if self.stack:
            self.stack[-1].children.append(node)
        else:
            self.root = node
        self.stack.append(node)

    def endElement(self, name):
        self.stack.pop()


_DEFUSED = {"EntitiesForbidden": "an entity declaration (<!ENTITY>)",
            "ExternalReferenceForbidden": "a reference to an external file or address"}


def _comments_as_mitsuba_reads_them(data):
    """`data` with '--' inside comments (and a comment's last '-') made spaces: XML forbids them, Mitsuba's parser
    (pugixml) reads them. Lines keep their numbers."""
    def fix(m):
        if m.group(1) is not None:  # a CDATA section, which may hold '<!--' as text: left as it is
            return m.group(1)
        inner = m.group(2).replace(b"--", b"- ")
        return b"<!--" + (inner[:-1] + b" " if inner.endswith(b"-") else inner) + b"-->"

    return re.sub(rb"(<!\[CDATA\[.*?\]\]>)|<!--(.*?)-->", fix, data, flags=re.S)


_BOMS = ((b"\xef\xbb\xbf", "utf-8-sig"), (b"\xff\xfe\x00\x00", "utf-32"), (b"\x00\x00\xfe\xff", "utf-32"),
         (b"\xff\xfe", "utf-16"), (b"\xfe\xff", "utf-16"), (b"<\x00\x00\x00", "utf-32-le"),
         (b"\x00\x00\x00<", "utf-32-be"), (b"<\x00", "utf-16-le"), (b"\x00<", "utf-16-be"))
_DECLARED = re.compile(rb"^(\s*<\?xml(?=\s)[^>]*?)\s+encoding\s*=\s*(['\"])([^'\"]*)\2")
# ASCII, its backslashes only in escapes that Python's escape codecs read (no invalid ones: they warn), and UTF-7's
_ASCII_PROBE = bytes(b for b in range(128) if b != 0x5C) + rb"\u0041\x41+AGE-"


def _ascii_charset(name):
    """Whether `name` is a character set Python knows that reads ASCII as ASCII (latin-1, windows-1252, ...):
    not UTF-16 or UTF-32, and no escape codec (unicode_escape, UTF-7) that would read a path's backslashes."""
    try:
        return _ASCII_PROBE.decode(name) == _ASCII_PROBE.decode("ascii")
    except (LookupError, ValueError):  # unknown, not a text encoding, a NUL in the name, ASCII it cannot read
        return False


def _as_utf8(data, path):
    """The document's bytes as UTF-8 with no encoding declared, so that the XML reader never meets an encoding
    it lacks (UTF-32) or a name it does not know: the encoding its first bytes show (a byte-order mark, or '<'
    in UTF-16/32), else the declared one where it is a character set Python knows (`_ascii_charset`) and the
    bytes decode, else UTF-8 — Mitsuba's reader (pugixml) also goes by the first bytes and reads an unknown
    declaration as UTF-8."""
    encoding = next((name for bom, name in _BOMS if data.startswith(bom)), None)
    if encoding is not None:
        try:
            data = data.decode(encoding).encode("utf-8")
        except UnicodeDecodeError as exc:
            raise ProbvisError(f"{path}: not {encoding.split('-sig')[0].upper()} text as its first bytes say "
                               f"(byte {exc.start}): save it as UTF-8") from None
    declared = _DECLARED.match(data)
    if declared is None:
        return data
    name = declared.group(3).decode("ascii", "replace").strip()
    start, end = declared.end(1), declared.end()  # the declaration blanked: lines and offsets stay where they were
    data = data[:start] + re.sub(rb"[^\r\n]", b" ", data[start:end]) + data[end:]
    if encoding is not None:
        return data
    known = _ascii_charset(name)
    if known:
        try:
            return data.decode(name).encode("utf-8")
        except UnicodeDecodeError:
            pass
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise ProbvisError(f"{path}:{line}: not UTF-8 text, and its declared encoding '{name}' "
                           f"{'does not read it either' if known else 'is unknown'}: save it as UTF-8") from None
    return data


def parse_tree(path):
    path = Path(path)
    if not path.exists():
        raise ProbvisError(missing_file(path, "scene file"))
    if not path.is_file():
        raise ProbvisError(f"{path}: not a regular file (a scene is an XML file)")
    if path.stat().st_size > MAX_SCENE_BYTES:
        raise ProbvisError(f"{path}: {path.stat().st_size / 2**20:.0f} MiB is larger than any scene file could be "
                           f"(at most {MAX_SCENE_BYTES >> 20} MiB; meshes belong in OBJ, PLY or serialized files)")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ProbvisError(f"cannot read scene file {path}: {exc.strerror}") from None
    data = _as_utf8(data, path)
    handler = _TreeBuilder()
    try:
        try:
            defusedxml.sax.parseString(data, handler)
        except xml.sax.SAXParseException:
            lenient = _comments_as_mitsuba_reads_them(data)
            if lenient == data:
                raise
            handler = _TreeBuilder()
            defusedxml.sax.parseString(lenient, handler)
    except xml.sax.SAXParseException as exc:
        raise ProbvisError(f"{path}:{exc.getLineNumber()}: malformed XML: {exc.getMessage()}") from None
    except defusedxml.DefusedXmlException as exc:
        lines = data.splitlines()
        line = next((i for i, text in enumerate(lines, 1) if b"<!ENTITY" in text), None) or \
            next((i for i, text in enumerate(lines, 1) if b"<!DOCTYPE" in text), None)
        where = f"{path}:{line}" if line else str(path)
        raise ProbvisError(f"{where}: {_DEFUSED.get(type(exc).__name__, 'this XML construct')} is not allowed in "
                           "scene files (remove it; Mitsuba's scenes use <default> and $parameters)") from None
    except ProbvisError as exc:
        raise ProbvisError(f"{path}:{exc}") from None
    if handler.root is None:
        raise ProbvisError(f"{path}: empty XML document")
    if "version" not in handler.root.attrs:  # as Mitsuba 3 requires of every file, included ones too
        raise ProbvisError(f"{path}:{handler.root.line}: <{handler.root.tag}>: missing version attribute (Mitsuba 3 "
                           f"reads a file whose root element has one, e.g. <{handler.root.tag} version=\"3.0.0\">)")
    return handler.root


_SAMPLING_WEIGHT = {"sampling_weight": ("float",)}  # every emitter's: see `_Reader.sampling_weight`
MAX_INCLUDES = 15  # <include> within <include>, as deep as Mitsuba's parser allows
MAX_INCLUDED = 100_000  # elements brought in by includes in all: files that include each other many times over
# would otherwise multiply a few kilobytes into gigabytes


def _depth(node):
    return 1 + max((_depth(ch) for ch in node.children), default=0)


def _size(node):
    return 1 + sum(_size(ch) for ch in node.children)


def with_includes(root, path, fail, filename):
    """The document with each `<include filename=.../>` replaced, as Mitsuba's parser does, by the included file's
    elements: the children of its `<scene>`, or its root element itself. `filename(node, defaults)` gives an
    include's file name, its parameters substituted from the top-level `<default>` elements above it. The file is
    looked for beside the file that includes it, then beside the scene file; its elements keep their own file
    and line for messages. Then every element is numbered in document order."""
    scene_folder = Path(path).parent
    brought = [0]
    defaults = []  # the top-level <default> elements so far, in document order

    def expand(node, file, chain, depth):
        out = []
        for ch in node.children:
            if ch.tag != "include":
                if ch.tag == "default" and depth == 1:
                    defaults.append(ch)
                expand(ch, file, chain, depth + 1)
                out.append(ch)
                continue
            extra = set(ch.attrs) - {"filename"}
            if extra or "filename" not in ch.attrs:
                fail(ch, "an <include> takes one attribute, filename" if extra else "missing attribute 'filename'")
            name = filename(ch, list(defaults))
            here = Path(file).parent if file is not None else scene_folder
            target = next((f / name for f in (here, scene_folder) if (f / name).is_file()), here / name)
            if target.is_dir():
                fail(ch, f"included file '{name}' is a folder ({target}): include a scene file")
            if target.exists() and not target.is_file():  # /dev/null, a FIFO
                fail(ch, f"included file '{name}': {missing_file(target, 'scene file')}")
            if not target.is_file():
                fail(ch, f"included file '{name}' not found (looked beside {'this file and ' if file else ''}"
                         f"the scene file{f', {here}' if file else ''})")
            if target.resolve() in chain:
                fail(ch, f"'{name}' includes itself ({' -> '.join(p.name for p in chain + [target])})")
            if len(chain) > MAX_INCLUDES:
                fail(ch, f"includes nested more than {MAX_INCLUDES} deep")
            try:  # a file the process may not read is named at its <include>, as every other include mistake
                target.open("rb").close()
            except OSError as exc:
                fail(ch, f"cannot read included file '{name}': {exc.strerror or exc}")
            included = parse_tree(target)
            elements = included.children if included.tag == "scene" else [included]
            included.attrs.pop("version", None)
            for e in elements:
                if depth + _depth(e) > MAX_NESTING:
                    fail(ch, f"with '{name}' included here, elements nest more than {MAX_NESTING} deep")
                brought[0] += _size(e)
                _set_file(e, target)
            if brought[0] > MAX_INCLUDED:
                fail(ch, f"the includes bring more than {MAX_INCLUDED:,} elements in all (files included many "
                         "times over?)")
            holder = Node("scene", {}, included.line, elements, target)
            expand(holder, target, chain + [target.resolve()], depth)
            out.extend(holder.children)
        node.children = out

    expand(root, None, [Path(path).resolve()], 1)
    for i, node in enumerate(_document_order(root)):
        node.order = i
    return root


def _set_file(node, file):
    node.file = file
    for ch in node.children:
        _set_file(ch, file)


def _document_order(node):
    yield node
    for ch in node.children:
        yield from _document_order(ch)


_APPROXIMATED_BSDFS = {"plastic", "roughplastic", "conductor", "roughconductor", "dielectric", "thindielectric",
                       "roughdielectric", "principled", "principledthin", "blendbsdf", "mask", "bumpmap", "normalmap",
                       "pplastic", "hair", "measured", "polarizer", "retarder"}
_MICROFACET = ("distribution", "alpha", "alpha_u", "alpha_v", "sample_visible")
_BSDF_PARAMETERS = {  # Mitsuba 3's parameters (properties and named textures) of the BSDFs probvis approximates
    "plastic": ("diffuse_reflectance", "specular_reflectance", "int_ior", "ext_ior", "nonlinear"),
    "roughplastic": ("diffuse_reflectance", "specular_reflectance", "int_ior", "ext_ior", "nonlinear",
                     "distribution", "alpha", "sample_visible"),
    "conductor": ("material", "eta", "k", "specular_reflectance"),
    "roughconductor": ("material", "eta", "k", "specular_reflectance") + _MICROFACET,
    "dielectric": ("int_ior", "ext_ior", "specular_reflectance", "specular_transmittance"),
    "thindielectric": ("int_ior", "ext_ior", "specular_reflectance", "specular_transmittance"),
    "roughdielectric": ("int_ior", "ext_ior", "specular_reflectance", "specular_transmittance") + _MICROFACET,
    "principled": ("base_color", "roughness", "anisotropic", "metallic", "spec_trans", "eta", "specular", "spec_tint",
                   "sheen", "sheen_tint", "clearcoat", "clearcoat_gloss", "diffuse_reflectance_sampling_rate",
                   "main_specular_sampling_rate", "clearcoat_sampling_rate"),
    "principledthin": ("base_color", "roughness", "anisotropic", "spec_trans", "eta", "spec_tint", "sheen",
                       "sheen_tint", "flatness", "diff_trans", "diffuse_reflectance_sampling_rate",
                       "specular_reflectance_sampling_rate", "specular_transmittance_sampling_rate",
                       "diffuse_transmittance_sampling_rate"),
    "blendbsdf": ("weight",),
    "mask": ("opacity",),
    "bumpmap": ("scale",),
    "normalmap": ("normalmap",),
    "pplastic": ("diffuse_reflectance", "specular_reflectance", "int_ior", "ext_ior", "alpha", "distribution"),
    "hair": ("eumelanin", "pheomelanin", "sigma_a", "scale", "longitudinal_roughness", "azimuthal_roughness",
             "scale_tilt", "int_ior"),
    "measured": ("filename",),
    "polarizer": ("theta", "transmittance", "polarizing"),
    "retarder": ("theta", "delta", "transmittance"),
}
_NESTED_BSDFS = {"blendbsdf": 2, "mask": 1, "bumpmap": 1, "normalmap": 1}  # the others nest none
# how the approximated BSDFs' parameters are given (Mitsuba's types); the others are colours or numbers:
# <rgb>, <spectrum>, <float> or a texture
_FLAG_PARAMETERS = {"nonlinear", "sample_visible", "polarizing"}
_NAME_PARAMETERS = {"material", "distribution", "filename"}
_IOR_PARAMETERS = {"int_ior", "ext_ior"}  # a number or a material's name
_DISTRIBUTIONS = ("beckmann", "ggx")
_UNBOUNDED_RGB = {"eta", "k", "sigma_a", "theta", "delta"}  # the approximated BSDFs' values that Mitsuba reads
# unbounded from an <rgb>; it refuses one outside [0, 1] for every other (an sRGB reflectance)
_FLOAT_ONLY = {("principled", "eta"), ("principled", "specular")} | {  # and every *_sampling_rate
    ("hair", name) for name in ("eumelanin", "pheomelanin", "scale", "longitudinal_roughness", "azimuthal_roughness",
                                "scale_tilt")}
_PROPERTY_TAGS = {"integer", "float", "boolean", "string", "rgb", "spectrum", "point", "vector", "transform"}
_SAMPLERS = {"independent": (), "stratified": ("jitter",), "multijitter": ("jitter",),  # their own parameters
             "orthogonal": ("jitter", "strength"), "ldsampler": ()}  # beside sample_count and seed
MAX_SAMPLER_SEED = 2 ** 32 - 1  # a Mitsuba sampler's seed is a 32-bit unsigned integer
BITMAP_FORMATS = ("auto", "variant", "float16", "uint8")
def _invertible_affine(m):
    """Whether the 4x4 transform `m` is affine (last row 0 0 0 1) with an invertible linear part, judged
    independently of its overall scale."""
    size = np.abs(m[:3, :3]).max()
    return bool(size > 0 and abs(np.linalg.det(m[:3, :3] / size)) >= 1e-12 and np.all(m[3] == (0, 0, 0, 1)))


_EMISSION_NAMES = ("radiance", "intensity", "irradiance")  # a spectrum's meaning: emission, else a reflectance


@functools.cache
def _equal_energy():
    """The sRGB of a flat emission spectrum of 1 over 360-830 nm (CIE illuminant E), what Mitsuba's RGB variants
    read for <spectrum name="radiance" value="1"/>: (1.205, 0.948, 0.909). Its tables load on first use."""
    return spectrum_to_rgb(np.array([360.0, 830.0]), np.ones(2), reflectance=False)


MAX_VALUE_CHARS = 1 << 20  # an attribute's value once its $parameters are substituted
_VAR = re.compile(r"\$(\w+)")  # a parameter's name in a value, where every declared name is a word


def _by_name(node):
    """The property elements among `node`'s children by their name: where a value's error is located."""
    return {ch.attrs.get("name"): ch for ch in node.children if ch.tag in _PROPERTY_TAGS}


def _unique_ids(root, fail, line_of):
    """Every `id` of the file once, as Mitsuba requires; the element of each id. Ids made of parameters
    (`id="$name"`) are checked as their elements define them (`_Reader.define`)."""
    seen, todo = {}, [root]
    while todo:
        node = todo.pop()
        key = node.attrs.get("as") if node.tag == "alias" else node.attrs.get("id") if node.tag != "ref" else None
        if key is not None and "$" not in key:
            if key in seen:
                first, later = sorted((seen[key], node), key=lambda n: n.order)
                fail(later, f"duplicate id '{key}' (first defined on {line_of(first, later)})")
            seen[key] = node
        todo.extend(node.children)
    return seen


class _Reader:
    def __init__(self, path, overrides, strict=False):
        self.path = Path(path)
        self.inputs = [self.path]  # every file the scene reads, for the outputs that must not replace one
        self.strict = strict
        self.approximated = set()  # plugin types already warned about
        self.overrides = {k: str(v) for k, v in overrides.items()}
        self.old_version = None  # a Mitsuba 0.x scene's version, which its errors name
        self.defaults = {}
        self.default_nodes = {}  # the element of each <default>
        self.used = set()  # overridden parameters the scene refers to
        self.ids = {}
        self.id_defined = {}  # the element that defined each id
        self.referenced = set()  # ids a <ref> resolved
        self.reading_ahead = []  # top-level elements read before their turn, for a <ref> above them (innermost last)
        self.images = {}  # decoded image files by (resolved path, raw)
        self.search_paths = []  # the folders of <path> elements, searched before the scene's
        self.hide_emitters = False  # the integrator's option
        self.dark = []  # (element, kind, why) of area emitters on shapes without area (`dark_emitters`)
        self.emitter_elements = []  # (its shape or None, element) of every <emitter>, in order (`zero_power`)
        self.unweighted = []  # elements of the emitters of sampling_weight 0 (`unsampled_emitters`)
        self.compensated = None  # an envmap with mis_compensation (`compensated_environment`)
        self.weighted = []  # emitters with a sampling_weight probvis leaves aside (`unsampled_emitters`)
        self.sampled = 0  # emitters of a positive (or no) sampling_weight
        self.bsdf_samples = 1  # the integrator's: Mitsuba's path and direct integrators sample the BSDF by default
        self.root = None  # the document's tree, once parsed

    # --- errors and values -------------------------------------------------------------------
    def fail(self, node, msg):
        variables = self._variables()
        given = sorted({m.group(1) for v in node.attrs.values() for m in variables.finditer(v)} & set(self.overrides))
        if given:  # the value came from the command line, not from the line named
            msg += f" (with {', '.join(f'-D {n}={self.overrides[n]}' for n in given)})"
        if self.old_version and ("unsupported" in msg or "unknown" in msg):  # a name 0.x spelt otherwise
            msg += (f" (the scene is in Mitsuba {self.old_version}'s format; probvis reads Mitsuba 3's, whose names "
                    "are snake_case, such as sample_count for sampleCount: convert it)")
        raise ProbvisError(f"{self.where(node)}: <{node.tag}>: {msg}")

    def where(self, node):
        """file:line of an element (the included file's, for an element an <include> brought)."""
        return f"{node.file or self.path}:{node.line}"

    def line_of(self, target, node):
        """Where `target` stands, as seen from `node`: its line, or file:line where it is in another file."""
        return f"line {target.line}" if target.file == node.file else self.where(target)

    def checked(self, node, fn, *args):
        """fn(*args), its ProbvisError located at the node's line."""
        try:
            return fn(*args)
        except ProbvisError as exc:
            self.fail(node, str(exc))

    def attr(self, node, key, default=None, required=True):
        if key not in node.attrs:
            if required and default is None:
                self.fail(node, f"missing attribute '{key}'")
            return default
        raw = node.attrs[key]

        def sub(m):
            name = m.group(1)
            if name in self.overrides:
                self.used.add(name)
                return self.overrides[name]
            if name in self.defaults:
                return self.defaults[name]
            later = next((ch for ch in getattr(self.root, "children", ()) if ch.tag == "default"
                          and ch.attrs.get("name") == name), None)
            if later is node:
                self.fail(node, f"parameter '${name}' refers to itself")
            if later is not None:
                self.fail(node, f"parameter '${name}' is declared on {self.line_of(later, node)}, after this use: "
                                "move its <default> above")
            self.fail(node, f"undefined parameter '${name}' (declare it with <default> or pass -D {name}=...)")

        variables = self._variables()
        if "$" in variables.sub("", raw):  # Mitsuba: "undefined parameter: $"
            self.fail(node, f"attribute '{key}': '{raw}' has a '$' that starts no parameter's name (a "
                            "parameter is written $name; Mitsuba's values cannot hold a '$' otherwise)")
        size = len(raw) + sum(len(self.overrides.get(m.group(1), self.defaults.get(m.group(1), ""))) - len(m.group(0))
                              for m in variables.finditer(raw))
        if size > MAX_VALUE_CHARS:  # parameters made of parameters grow exponentially ("billion laughs")
            self.fail(node, f"attribute '{key}' expands to {size:,} characters through its parameters, more than "
                            f"{MAX_VALUE_CHARS:,}: check the <default> values that refer to other parameters")
        return variables.sub(sub, raw)

    def _variables(self):
        """`$name` of any parameter, as Mitsuba substitutes it: a declared name wherever its text stands after a
        '$', also before more letters ('$name_lod1' is `name` then '_lod1'), longest first; then any word (an
        undeclared one is named as such)."""
        declared = sorted({*self.defaults, *self.overrides}, key=len, reverse=True)
        if not declared:
            return _VAR
        return re.compile(r"\$(" + "|".join(map(re.escape, declared)) + r"|\w+)")

    def check_attrs(self, node, allowed):
        extra = set(node.attrs) - set(allowed)
        if extra:
            self.fail(node, f"unsupported attribute(s): {', '.join(sorted(extra))}")

    def number(self, node, key, default=None):
        """A finite number from attribute `key` of `node`."""
        raw = self.attr(node, key, default)
        try:
            v = _float(raw)
        except ValueError:
            self.fail(node, f"attribute '{key}': '{raw}' is not a number")
        if not np.isfinite(v):
            self.fail(node, f"attribute '{key}': non-finite value '{raw}'")
        return v

    def numbers(self, node, text, count=None):
        try:
            vals = [_float(x) for x in re.split(r"[,\s]+", text.strip()) if x]
        except ValueError:
            self.fail(node, f"expected numbers, got '{text}'")
        if count is not None and len(vals) not in count:
            want = " or ".join(str(c) for c in count)
            self.fail(node, f"expected {want} numbers, got '{text}'")
        if not all(np.isfinite(vals)):
            self.fail(node, f"non-finite number in '{text}'")
        return vals

    def refuse_mixed(self, node, names=("x", "y", "z")):
        """A 'value' beside x/y/z is refused, as Mitsuba refuses it: which one wins would be a guess."""
        mixed = [a for a in names if a in node.attrs]
        if "value" in node.attrs and mixed:
            self.fail(node, f"give either 'value' or {'/'.join(names)}, not both (here also "
                            f"{', '.join(map(repr, mixed))})")

    def value(self, node):
        """Value of a property element (integer, float, boolean, string, rgb, spectrum, point, vector)."""
        tag = node.tag
        if tag in ("point", "vector"):
            self.check_attrs(node, ("name", "x", "y", "z", "value"))
            self.refuse_mixed(node)
            if "value" in node.attrs:
                return np.array(self.numbers(node, self.attr(node, "value"), (1, 3))) * np.ones(3)
            return np.array([self.number(node, a, "0") for a in "xyz"])
        if tag == "spectrum" and "filename" in node.attrs:
            self.check_attrs(node, ("name", "filename"))
            return self.sampled_spectrum(node, self.spectrum_file(node))
        self.check_attrs(node, ("name", "value"))
        raw = self.attr(node, "value")
        try:
            if tag == "integer":
                if raw.strip().startswith("+"):  # Mitsuba's integer parser refuses a sign of +, not its floats'
                    self.fail(node, f"'{raw}' is not a valid integer: Mitsuba reads no '+' sign on an integer (write "
                                    f"'{raw.strip()[1:]}')")
                return _int(raw)
            if tag == "float":
                v = _float(raw)
                if not np.isfinite(v):
                    self.fail(node, f"non-finite value '{raw}'")
                return v
        except ValueError:
            self.fail(node, f"'{raw}' is not a valid {tag}")
        if tag == "boolean":
            if raw.lower() not in ("true", "false"):
                self.fail(node, f"'{raw}' is not a boolean (true/false)")
            return raw.lower() == "true"
        if tag == "string":
            return raw
        if tag == "spectrum" and ":" in raw:
            return self.sampled_spectrum(node, raw)
        if tag in ("rgb", "spectrum"):
            vals = self.numbers(node, raw, None if tag == "spectrum" else (1, 3))
            if tag == "spectrum" and len(vals) != 1:
                self.fail(node, f"a spectrum is one value or wavelength:value pairs, got '{raw}'")
            if len(vals) not in (1, 3):
                self.fail(node, f"expected 1 or 3 values, got '{raw}'")
            if tag == "spectrum" and node.attrs.get("name") in _EMISSION_NAMES:
                return vals[0] * _equal_energy()  # as Mitsuba: a flat emission spectrum, not a grey RGB
            return np.array(vals, dtype=np.float64) * np.ones(3)
        self.fail(node, "unsupported property type")

    def spectrum_file(self, node):
        """A spectrum file's `wavelength value` lines (Mitsuba's .spd; '#' starts a comment) as `w:v` pairs."""
        path = self.input_file(node, self.attr(node, "filename"))
        if not path.is_file():
            self.fail(node, missing_file(path, "spectrum file") if not path.exists() else
                      f"spectrum file {path} is not a regular file")
        if path.stat().st_size > MAX_VALUE_CHARS:
            self.fail(node, f"spectrum file {path} is larger than {MAX_VALUE_CHARS:,} bytes: not a spectrum")
        pairs = []
        try:
            lines = path.read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            self.fail(node, f"cannot read spectrum file {path}: {getattr(exc, 'strerror', None) or exc}")
        for number, line in enumerate(lines, 1):
            words = line.split("#", 1)[0].split()
            if not words:
                continue
            try:
                if len(words) != 2 or not all(np.isfinite(_float(w)) for w in words):
                    raise ValueError
            except ValueError:
                self.fail(node, f"{path}:{number}: expected a wavelength and a value (two finite numbers), got "
                                f"'{line.strip()}'")
            pairs.append(":".join(words))
        return ", ".join(pairs)

    def sampled_spectrum(self, node, raw):
        """RGB of `wavelength:value` pairs, as Mitsuba's RGB variants reduce them (emission for radiance,
        intensity and irradiance, else a reflectance)."""
        try:
            pairs = [tuple(_float(x) for x in item.split(":")) for item in re.split(r",\s*|\s+(?=\d)", raw.strip())
                     if item]
            w, v = np.array(pairs, dtype=np.float64).T
        except ValueError:
            self.fail(node, f"expected wavelength:value pairs, got '{raw}'")
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(v))):
            self.fail(node, f"non-finite wavelength or value in '{raw}'")
        if len(w) < 2 or np.any(np.diff(w) <= 0):
            self.fail(node, "a sampled spectrum needs two or more values at increasing wavelengths")
        if np.abs(v).max() > MAX_EMISSION:
            self.fail(node, f"spectrum value {np.abs(v).max():g} is out of range (at most {MAX_EMISSION:g})")
        emission = node.attrs.get("name") in _EMISSION_NAMES
        if node.attrs.get("name") == "reflectance" and (np.any(v < 0) or np.any(v > 1)):
            self.fail(node, "reflectance must be within [0, 1] at every wavelength")
        rgb = spectrum_to_rgb(w, v, reflectance=not emission)
        if np.any(v > 0) and not np.any(rgb > 0):
            self.fail(node, f"wavelengths {w.min():g}-{w.max():g} nm lie outside 360-830 nm: this "
                            f"{'emission' if emission else 'reflectance'} would be black (give the spectrum in "
                            "nanometres over the visible range)")
        if emission and np.all(v >= 0) and np.any(rgb < 0):
            warnings.warn(f"{self.where(node)}: this emission spectrum lies outside the sRGB gamut (RGB "
                          f"{', '.join(f'{c:.3g}' for c in rgb)}): its negative components are clamped to 0",
                          stacklevel=2)
            rgb = np.maximum(rgb, 0.0)
        return rgb

    def transform(self, node):
        self.check_attrs(node, ("name",))
        m = np.eye(4)
        for op in node.children:
            try:
                with np.errstate(all="ignore"):  # an overflow is named below, at the operation that made it
                    m = self.transform_op(op) @ m
            except ValueError as exc:
                self.fail(op, str(exc))
            if not np.all(np.abs(m) <= MAX_TRANSFORM):
                self.fail(op, f"the transform's entries go beyond ±{MAX_TRANSFORM:g} here (or are not numbers): a "
                              "scale, axis or matrix this large overflows; rescale the scene")
        return m

    def transform_op(self, op):
        t = op.tag

        def vec(names=("x", "y", "z"), default="0"):
            if "value" in op.attrs:
                self.refuse_mixed(op, names)
                vals = self.numbers(op, self.attr(op, "value"), (1, 3))
                return np.array(vals) * np.ones(3)
            return np.array([self.number(op, a, default) for a in names])

        if t == "translate":
            self.check_attrs(op, ("x", "y", "z", "value"))
            return tf.translate(vec())
        if t == "scale":
            self.check_attrs(op, ("x", "y", "z", "value"))
            return tf.scale(vec(default="1"))
        if t == "rotate":
            self.check_attrs(op, ("x", "y", "z", "value", "angle"))
            return tf.rotate(vec(), self.number(op, "angle"))
        if t == "lookat":
            self.check_attrs(op, ("origin", "target", "up"))
            o = self.numbers(op, self.attr(op, "origin"), (3,))
            tg = self.numbers(op, self.attr(op, "target"), (3,))
            up = self.numbers(op, self.attr(op, "up"), (3,)) if "up" in op.attrs else None  # see tf.look_at
            if not (np.all(np.abs(o) <= MAX_COORDINATE) and np.all(np.abs(tg) <= MAX_COORDINATE)):
                self.fail(op, f"lookat's origin and target must lie within ±{MAX_COORDINATE:g}: rescale the scene")
            return tf.look_at(o, tg, up)
        if t == "matrix":
            self.check_attrs(op, ("value",))
            vals = self.numbers(op, self.attr(op, "value"), (9, 16))
            if len(vals) == 9:
                m = np.eye(4)
                m[:3, :3] = np.reshape(vals, (3, 3))
                return m
            return np.reshape(vals, (4, 4))
        self.fail(op, "unsupported transform operation (use translate, scale, rotate, lookat or matrix)")

    def once(self, ch, name, lines):
        """Refuse a parameter `name` given a second time (a property or a nested object, as Mitsuba does)."""
        if name in lines:
            self.fail(ch, f"parameter '{name}' is given twice (first on line {lines[name]})")
        lines[name] = ch.line

    def declare_default(self, ch):
        """A `<default>`: its parameter's value from here on in document order, at the top level or inside an
        element (as Mitsuba's parser takes it); Mitsuba keeps a parameter's first."""
        self.check_attrs(ch, ("name", "value"))
        name = self.attr(ch, "name")
        if not name.strip():
            self.fail(ch, "a <default> needs a parameter name (it is empty)")
        if "value" not in ch.attrs:
            self.fail(ch, f"missing attribute 'value' of parameter '{name}'")
        first = self.default_nodes.get(name)
        if first is ch:  # an element read again (a <ref>'s object)
            return
        if first is not None:
            warnings.warn(f"{self.where(ch)}: <default> of '{name}' declared again (first on "
                          f"{self.line_of(first, ch)}, whose value is kept)", stacklevel=3)
            return
        self.default_nodes[name] = ch
        # `$b` in a default: the parameters known so far (none needed where -D gives the parameter)
        self.defaults[name] = self.default_value(ch, name)

    def params(self, node, allowed_props, allowed_objects=(), unnamed=None, unknown=None):
        """Split children into a {name: value} dict and a list of nested objects, rejecting anything else and any
        name given twice (a nested object without a name counts as `unnamed`, the one it stands for); `unknown(ch)`,
        if given, may refuse an element with a message of its own first."""
        props, objects, lines = {}, [], {}
        for ch in node.children:
            if ch.tag in _PROPERTY_TAGS:
                name = self.attr(ch, "name")
                self.once(ch, name, lines)
                if name not in allowed_props:
                    self.fail(ch, f"unsupported parameter '{name}' for {node.tag} '{node.attrs.get('type', '')}'")
                props[name] = self.transform(ch) if ch.tag == "transform" else self.value(ch)
                if allowed_props[name] is not None and ch.tag not in allowed_props[name]:
                    self.fail(ch, f"parameter '{name}' must be given as <{'/'.join(allowed_props[name])}>")
            elif ch.tag in allowed_objects:
                name = self.attr(ch, "name", unnamed, required=False)
                if name is not None:
                    self.once(ch, name, lines)
                objects.append(ch)
            elif ch.tag == "default":
                if self.reading_ahead:  # read at a <ref> above: its place in the document is not reached yet
                    self.fail(ch, "a <default> inside an element that a <ref> above it uses: probvis reads that "
                                  "element at the <ref>, before the parameters declared between them; move the "
                                  "<default> to the top level")
                self.declare_default(ch)
            else:
                if unknown is not None:
                    unknown(ch)
                self.fail(ch, f"unsupported element inside <{node.tag}>")
        return props, objects

    def nested_checker_colour(self, ch):
        """A checkerboard's colour given as a nested texture (which Mitsuba reads) is refused in one line."""
        if ch.tag in ("texture", "ref"):
            self.fail(ch, f"a checkerboard's '{ch.attrs.get('name', 'color0')}' is a texture: probvis reads a "
                          "checkerboard's colours as <rgb>, <spectrum> or <float> only")

    def textured_emission(self, ch):
        """A texture given as an emitter's radiance or intensity, which probvis does not take."""
        if ch.tag == "texture":
            self.fail(ch, f"an emitter's {ch.attrs.get('name', 'radiance')} given as a texture is not supported by "
                          "probvis: give an <rgb> or <spectrum> (a textured area light could be split into shapes of "
                          "one colour each)")

    def sampling_weight(self, node, props, delta=False):
        """Mitsuba's emitter `sampling_weight`: how often the emitter is sampled, which changes the noise and not
        the expected image. probvis samples emitters by power, so it is checked and left aside, with a warning. At
        0 Mitsuba's emitter sampling never picks the emitter: a `delta` one (point, spot, directional) then adds
        nothing, which is refused; an area or environment light is still found by BSDF sampling."""
        w = props.get("sampling_weight", 1.0)
        zero = w == 0 or (0 < w < 1 and np.float32(w) == 0)  # Mitsuba's weights are single precision
        if w > 0 and not zero:
            self.sampled += 1
        if "sampling_weight" in props:
            if not (0 <= w <= MAX_EMISSION and (not zero or not delta)):
                span = f"above 0 and at most {MAX_EMISSION:g}" if delta else f"from 0 to {MAX_EMISSION:g}"
                why = (" (at 0 Mitsuba never samples this light, which only emitter sampling reaches: remove it, or "
                       "give a positive weight)") if zero else ""
                single = " (0 in Mitsuba's single precision)" if zero and w > 0 else ""
                self.fail(_by_name(node)["sampling_weight"], f"sampling_weight must be {span}, got {w:g}{single}{why}")
            if zero:  # said once the integrator is read (`unsampled_emitters`)
                self.unweighted.append(_by_name(node)["sampling_weight"])
                return
            self.weighted.append(node)  # said once for all (`unsampled_emitters`)

    # --- plugins -----------------------------------------------------------------------------
    def bsdf(self, node):
        """Returns (reflectance, twosided, texture or None, back): `back` is None, or the (reflectance, texture)
        seen from behind a `twosided` of two BSDFs."""
        if node.tag == "ref":
            return self.resolve(node, "bsdf")
        self.check_attrs(node, ("type", "id", "name"))
        kind = self.attr(node, "type")
        if kind == "diffuse":
            props, objs = self.params(node, {"reflectance": ("rgb", "spectrum", "float")}, ("texture", "ref"),
                                      unnamed="reflectance")
            refl = props.get("reflectance", np.full(3, 0.5)) * np.ones(3)
            texture = None
            for ch in objs:
                if self.attr(ch, "name", "reflectance", required=False) != "reflectance":
                    self.fail(ch, "a diffuse bsdf takes only a 'reflectance' texture")
                texture = self.texture(ch)
                refl = texture.mean() if texture is not None else np.full(3, 0.5)
                if texture is not None and texture.image is not None and (texture.image.min() < 0
                                                                            or texture.image.max() > 1):
                    warnings.warn(f"{self.where(ch)}: the reflectance texture has values from "
                                  f"{texture.image.min():g} to {texture.image.max():g}, outside [0, 1]: those texels "
                                  "reflect negative light or more than they receive (Mitsuba renders them as given)",
                                  stacklevel=2)
            if texture is None and (np.any(refl < 0) or np.any(refl > 1)):
                self.fail(node, "reflectance must be within [0, 1]")
            out = (refl, False, texture, None)
        elif kind == "twosided":
            _, objs = self.params(node, {}, ("bsdf", "ref"))
            if len(objs) not in (1, 2):
                self.fail(node, f"twosided takes one nested bsdf (both sides) or two (the front's, then the back's), "
                                f"got {len(objs)}")
            sides = [self.bsdf(ch) for ch in objs]  # a nested twosided shows its front, the way Mitsuba turns it
            out = (sides[0][0], True, sides[0][2], (sides[1][0], sides[1][2]) if len(sides) == 2 else None)
        elif kind in _APPROXIMATED_BSDFS:
            colour = self.nearest_diffuse(node, kind)
            how = f"rendered as diffuse with reflectance {', '.join(f'{c:.3g}' for c in colour)}"
            if kind == "mask":  # its opacity lets shadow rays through in Mitsuba: here the shape is opaque
                self.approximate(node, "bsdf 'mask'", f"{how} and opaque: its opacity is ignored, so the shape "
                                                      "casts shadows where Mitsuba's lets light through", False)
            else:
                self.approximate(node, f"bsdf '{kind}'", how)
            out = (colour, kind in ("dielectric", "thindielectric", "roughdielectric"), None, None)
        else:
            self.fail(node, f"unsupported bsdf type '{kind}' (supported: diffuse, twosided; approximated as diffuse: "
                            f"{', '.join(sorted(_APPROXIMATED_BSDFS))})")
        if "id" in node.attrs:
            self.define(node, "bsdf", out)
        return out

    def approximate(self, node, what, how, exact_visibility=True):
        """Appearance (or, `exact_visibility` False, also visibility) probvis does not model: an error with
        --strict, else one warning per plugin type."""
        if self.strict:
            self.fail(node, f"{what} is approximated ({how}); drop --strict to render it anyway")
        if what not in self.approximated:
            self.approximated.add(what)
            note = "appearance approximated; visibility is exact" if exact_visibility else "visibility approximated"
            warnings.warn(f"{self.where(node)}: {what} {how} ({note})", stacklevel=2)

    def loose_params(self, node, kind):
        """The simple properties of a BSDF probvis approximates and its nested objects; a name that is not one of
        Mitsuba's parameters of that BSDF (`_BSDF_PARAMETERS`), or an element no BSDF takes, is refused as Mitsuba
        does."""
        props, objects, lines = {}, [], {}
        allowed = _BSDF_PARAMETERS[kind]

        def check(ch, name):
            if name not in allowed:
                self.fail(ch, f"unsupported parameter '{name}' for bsdf '{kind}' (its parameters: "
                              f"{', '.join(allowed)})")

        for ch in node.children:
            if ch.tag in ("rgb", "spectrum", "float", "integer", "boolean", "string"):
                name = self.attr(ch, "name")
                check(ch, name)
                self.once(ch, name, lines)
                want = (("boolean",) if name in _FLAG_PARAMETERS else ("string",) if name in _NAME_PARAMETERS
                        else ("float", "string") if name in _IOR_PARAMETERS else ("float",) if (kind, name) in
                        _FLOAT_ONLY or name.endswith("_sampling_rate") else ("rgb", "spectrum", "float"))
                if ch.tag not in want:
                    self.fail(ch, f"'{name}' of a {kind} bsdf is given as <{'> or <'.join(want)}>"
                                  f"{' or a <texture>' if 'rgb' in want else ''}")
                props[name] = self.value(ch)  # read and checked as diffuse's, though only its mean is modelled
                if ch.tag == "rgb" and name not in _UNBOUNDED_RGB and not np.all((props[name] >= 0) &
                                                                                  (props[name] <= 1)):
                    self.fail(ch, f"'{name}' of a {kind} bsdf is a reflectance: an <rgb> must be within [0, 1], got "
                                  f"{', '.join(f'{v:g}' for v in props[name])}")
            elif ch.tag in ("bsdf", "ref", "texture"):
                if "name" in ch.attrs:
                    name = self.attr(ch, "name")
                    if kind != "bumpmap" and (ch.tag == "texture" or ch.tag == "ref" and self.ref_kind(ch) ==
                                              "texture"):
                        check(ch, name)  # a named texture stands for a colour; a nested BSDF's name is free
                    self.once(ch, name, lines)
                objects.append(ch)
            else:
                self.fail(ch, f"unsupported element <{ch.tag}> inside <bsdf type='{kind}'>")
        return props, objects

    def texture(self, node):
        """A `bitmap` or `checkerboard` texture as a `Texture`; None (grey 0.5, with a warning) for other types."""
        if node.tag == "ref":
            return self.resolve(node, "texture")
        self.check_attrs(node, ("type", "id", "name"))
        kind = self.attr(node, "type")
        colour = ("rgb", "spectrum", "float")
        if kind == "bitmap":
            props, _ = self.params(node, {"filename": ("string",), "filter_type": ("string",),
                                          "wrap_mode": ("string",), "raw": ("boolean",), "to_uv": ("transform",),
                                          "format": ("string",), "accel": ("boolean",)})
            if "filename" not in props:
                self.fail(node, "bitmap needs a 'filename'")
            if props.get("format", "auto") not in BITMAP_FORMATS:
                self.fail(_by_name(node)["format"], f"unknown bitmap format '{props['format']}' (Mitsuba's: "
                                                     f"{', '.join(BITMAP_FORMATS)})")
            filt, wrap = props.get("filter_type", "bilinear"), props.get("wrap_mode", "repeat")
            if filt not in ("bilinear", "nearest"):
                self.fail(node, f"filter_type must be bilinear or nearest, got '{filt}'")
            if wrap not in WRAP_MODES:
                self.fail(node, f"wrap_mode must be one of {', '.join(WRAP_MODES)}, got '{wrap}'")
            image = self.image(node, self.input_file(node, props["filename"]), props.get("raw", False))
            out = Texture(BITMAP, self.checked(node, self.to_uv, props), image=image, wrap=WRAP_MODES[wrap],
                          bilinear=filt == "bilinear")
        elif kind == "checkerboard":
            props, _ = self.params(node, {"color0": colour, "color1": colour, "to_uv": ("transform",)},
                                   unknown=self.nested_checker_colour)
            colours = np.array([props.get("color0", 0.4) * np.ones(3), props.get("color1", 0.2) * np.ones(3)])
            if np.any(colours < 0) or np.any(colours > 1):
                self.fail(node, "checkerboard colours are reflectances: each must be within [0, 1]")
            out = Texture(CHECKERBOARD, self.checked(node, self.to_uv, props), colours=colours)
        elif kind in _APPROXIMATED_TEXTURES:
            self.approximate(node, f"texture '{kind}'", "rendered as grey 0.5")
            out = None
        else:
            self.fail(node, f"unsupported texture type '{kind}' (supported: bitmap, checkerboard; approximated as "
                            f"grey: {', '.join(sorted(_APPROXIMATED_TEXTURES))})")
        if "id" in node.attrs:
            self.define(node, "texture", out)
        return out

    def image(self, node, path, raw=False):
        """The linear RGB of image file `path` (`input_file`), decoded once per file however many shapes name it
        (read-only: textures share it)."""
        key = (os.path.realpath(path), raw)  # realpath: a loop of links is named by the reader, not raised here
        if key not in self.images:
            try:
                self.images[key] = read_linear_rgb(path, raw=raw)
            except ProbvisError as exc:
                self.fail(node, str(exc))
            self.images[key].flags.writeable = False
        return self.images[key]

    @staticmethod
    def to_uv(props):
        """The (2, 3) affine map of a texture's `to_uv` (the 4x4 transform's x and y rows, without z)."""
        m = props.get("to_uv", np.eye(4))[np.ix_([0, 1], [0, 1, 3])]
        if not np.all(np.abs(m) <= MAX_UV_SCALE):
            raise ProbvisError(f"to_uv has entries beyond ±{MAX_UV_SCALE:g} (a texture repeated that often is "
                               "uniform, and its coordinates lose all precision)")
        return m


    def nearest_diffuse(self, node, kind):
        """The diffuse colour nearest to a BSDF probvis does not model (documented in docs/decisions.md)."""
        props, objs = self.loose_params(node, kind)
        lines = _by_name(node)
        textures = [ch for ch in objs if ch.tag == "texture" or (ch.tag == "ref" and self.ref_kind(ch) == "texture")]
        # each read, though only a colour is used: a missing or broken file is an error, as in Mitsuba
        named = {ch.attrs.get("name"): self.texture(ch) for ch in textures}
        nested = [ch for ch in objs if ch.tag in ("bsdf", "ref") and ch not in textures]
        if len(nested) != _NESTED_BSDFS.get(kind, 0):
            want = _NESTED_BSDFS.get(kind, 0)
            self.fail(node, f"bsdf '{kind}' nests no other bsdf, got {len(nested)}" if want == 0 else
                      f"bsdf '{kind}' nests exactly {'one' if want == 1 else 'two'} bsdf{'s' * (want > 1)}, got "
                      f"{len(nested)}")

        if isinstance(props.get("distribution"), str):  # Mitsuba reads the name in any case
            props["distribution"] = props["distribution"].lower()
        if props.get("distribution", "beckmann") not in _DISTRIBUTIONS:
            self.fail(lines["distribution"], f"'distribution' of a {kind} bsdf is beckmann or ggx, got "
                                             f"'{props['distribution']}'")
        if "alpha" in props and ("alpha_u" in props or "alpha_v" in props) or ("alpha_u" in props) != (
                "alpha_v" in props):
            self.fail(node, f"a {kind} bsdf takes either alpha or both alpha_u and alpha_v")
        if "material" in props and ("eta" in props or "k" in props):
            self.fail(node, f"a {kind} bsdf takes either a material or eta and k, not both")
        for key in sorted(_IOR_PARAMETERS & props.keys()):  # unused by the approximation, but nonsense is refused
            if not 0.0 < self.ior(lines[key], props, key, None) < np.inf:
                self.fail(lines[key], f"{key} of a {kind} bsdf must be positive, got {props[key]:g}")
        if kind in ("roughdielectric", "roughplastic") and (  # as Mitsuba stores them, in single precision
                np.float32(self.ior(node, props, "int_ior", "bk7" if kind == "roughdielectric" else "polypropylene"))
                == np.float32(self.ior(node, props, "ext_ior", "air"))):
            self.fail(node, f"int_ior and ext_ior of a {kind} bsdf must differ (Mitsuba refuses equal ones: the "
                            "interface would not refract)")
        if kind.startswith("principled") and "eta" in props and not np.all(np.asarray(props["eta"]) > 0):
            self.fail(lines["eta"], f"eta of a {kind} bsdf must be positive (Mitsuba renders it as NaN), got "
                                    f"{', '.join(f'{v:g}' for v in np.ravel(props['eta']))}")
        if kind == "measured":
            if "filename" not in props:
                self.fail(node, "a measured bsdf needs a 'filename'")
            if not self.input_file(lines["filename"], props["filename"]).is_file():
                self.fail(lines["filename"], f"no file '{props['filename']}' for the measured bsdf")
        if kind in ("bumpmap", "normalmap") and len(textures) != 1:
            what = "height" if kind == "bumpmap" else "normals"
            self.fail(node, f"a {kind} bsdf needs exactly one nested texture (its {what}), got {len(textures)}")

        def colour(name, default):
            if name in named:  # a texture's mean; grey 0.5 for one probvis does not read
                return np.full(3, 0.5) if named[name] is None else np.clip(named[name].mean(), 0.0, 1.0)
            value = props.get(name, default)
            if isinstance(value, (str, bool)):
                self.fail(lines[name], f"'{name}' of a {kind} bsdf is a colour: give it as <rgb>, <spectrum>, "
                                       "<float> or a nested <texture>")
            value = np.ones(3) * value
            if not np.all(value >= 0.0):
                self.fail(lines[name], f"'{name}' of a {kind} bsdf must not be negative, got "
                                       f"{', '.join(f'{v:g}' for v in value)}")
            if name == "weight" and not np.all(value <= 1.0):
                self.fail(lines[name], f"a blendbsdf's weight is between 0 and 1, got "
                                       f"{', '.join(f'{v:g}' for v in value)}")
            return np.minimum(value, 1.0)

        if kind in ("plastic", "roughplastic"):
            return colour("diffuse_reflectance", 0.5)
        if kind == "principled":
            return colour("base_color", 0.5)
        if kind in ("conductor", "roughconductor"):
            material = props.get("material", "none")
            if not isinstance(material, str):
                self.fail(lines["material"], "a conductor's material is a name: give it as <string>")
            if material not in _CONDUCTORS:
                self.fail(node, f"unknown conductor material '{material}' (Mitsuba's: "
                                f"{', '.join(sorted(_CONDUCTORS))})")
            return colour("specular_reflectance", 1.0)
        if kind in ("dielectric", "thindielectric", "roughdielectric"):
            ior_in, ior_out = (self.ior(lines.get(key, node), props, key, default)  # positive: checked above
                               for key, default in (("int_ior", "bk7"), ("ext_ior", "air")))
            # Fresnel reflectance at normal incidence, ((n1 - n2) / (n1 + n2))^2, scaled by the larger index so
            # that no ratio overflows: 1 in the limit of a huge contrast
            a, b = ior_in / max(ior_in, ior_out), ior_out / max(ior_in, ior_out)
            return np.full(3, ((a - b) / (a + b)) ** 2)
        if kind == "blendbsdf":
            w = float(np.mean(colour("weight", 0.5)))
            return (1.0 - w) * self.bsdf(nested[0])[0] + w * self.bsdf(nested[1])[0]
        if nested:  # mask, bumpmap, normalmap: the BSDF they wrap
            return self.bsdf(nested[0])[0]
        return np.full(3, 0.5)

    def ior(self, node, props, key, default):
        """An index of refraction given as a number or by one of Mitsuba's material names."""
        value = props.get(key, default)
        if isinstance(value, (np.ndarray, bool)):
            self.fail(node, f"{key} is one number or a material name: give it as <float> or <string>")
        if isinstance(value, str):
            if value.lower() not in _IORS:
                self.fail(node, f"unknown material '{value}' for {key} (Mitsuba's: {', '.join(_IORS)})")
            value = _IORS[value.lower()]
        return value

    def define(self, node, kind, value, key=None):
        """Name `value` (a `kind`) by the node's id (or `key`, an alias), its parameters substituted (unique in the
        file: `_unique_ids`, and here for ids made of parameters)."""
        key = self.attr(node, "id") if key is None else key
        first = self.id_defined.setdefault(key, node)
        if first is not node:  # an element read again (a shapegroup's) defines its id again
            self.fail(node, f"duplicate id '{key}' (first defined on {self.line_of(first, node)})")
        self.ids[key] = (kind, value)

    def ref_kind(self, node):
        """The kind ('bsdf', 'texture', ...) of the object a `<ref>` names; None if it names nothing defined."""
        return self.ids.get(self.attr(node, "id", required=False), (None,))[0]

    def resolve(self, node, kind):
        self.check_attrs(node, ("id", "name"))
        key = self.attr(node, "id")
        if key not in self.ids:
            target = self.id_nodes.get(key)
            if target is None:
                self.fail(node, f"reference to unknown id '{key}'")
            if target.tag == kind and kind in ("bsdf", "texture") and any(ch is target for ch in self.root.children):
                self.read_ahead(node, target)
            if key not in self.ids:  # a shapegroup further down, or not the kind asked for
                group = target.tag == "shape" and target.attrs.get("type") == "shapegroup"
                if target.tag == kind or (group and kind == "shapegroup"):
                    self.fail(node, f"id '{key}' is defined after this reference ({self.line_of(target, node)}): "
                                    "move it above")
                self.fail(node, f"id '{key}' is a <{target.tag}>, not a {kind}")
        k, val = self.ids[key]
        if k != kind:
            self.fail(node, f"id '{key}' is a {k}, not a {kind}")
        self.referenced.add(key)
        return val

    def read_ahead(self, node, target):
        """Read the top-level BSDF or texture `target` that `node`, above it, refers to, as Mitsuba resolves a
        reference to an object defined further down; one that refers back to itself on the way is refused."""
        if any(t is target for t in self.reading_ahead):
            chain = " -> ".join(f"'{t.attrs.get('id')}'" for t in self.reading_ahead + [target])
            self.fail(node, f"references that go round in a circle ({chain})")
        self.reading_ahead.append(target)
        self.bsdf(target) if target.tag == "bsdf" else self.texture(target)
        self.reading_ahead.pop()

    def emitter_radiance(self, node):
        self.check_attrs(node, ("type", "id", "name"))
        kind = self.attr(node, "type")
        if kind != "area":
            self.fail(node, f"unsupported emitter type '{kind}' (supported: area, attached to a shape)")
        props, _ = self.params(node, {"radiance": ("rgb", "spectrum", "float"), **_SAMPLING_WEIGHT},
                               unknown=self.textured_emission)
        self.sampling_weight(node, props)
        return self.emission(node, "radiance", props.get("radiance", np.ones(3)))  # Mitsuba's default: 1

    def emission(self, node, name, value):
        """An emitter's radiance, intensity or scale as RGB: non-negative and at most MAX_EMISSION."""
        rgb = np.asarray(value, dtype=np.float64) * np.ones(3)
        if np.any(rgb < 0):
            self.fail(node, f"{name} must be non-negative")
        if np.any(rgb > MAX_EMISSION):
            self.fail(node, f"{name} {rgb.max():g} is out of range (at most {MAX_EMISSION:g}: rescale the scene's "
                            "emitters together)")
        if np.any((rgb > 0) & (rgb < 1.0 / MAX_EMISSION)):
            self.fail(node, f"{name} {rgb[rgb > 0].min():g} is out of range (non-zero values must be at least "
                            f"{1.0 / MAX_EMISSION:g}, or they vanish in single precision: rescale the scene's emitters "
                            "together)")
        return rgb

    def delta_emitter(self, node, builder):
        """A top-level `point` or `spot` emitter."""
        self.check_attrs(node, ("type", "id", "name"))
        kind = self.attr(node, "type")
        if kind not in ("point", "spot", "directional", "envmap", "constant"):
            self.fail(node, f"unsupported emitter type '{kind}' at top level (supported: point, spot, directional, "
                            "envmap, constant; area emitters attach to shapes)")
        if kind in ("envmap", "constant"):
            self.environment(node, kind, builder)
            return
        if kind == "directional":
            props, _ = self.params(node, {"irradiance": ("rgb", "spectrum", "float"), "direction": ("vector",),
                                          "to_world": ("transform",), **_SAMPLING_WEIGHT})
            self.sampling_weight(node, props, delta=True)
            if "direction" in props and "to_world" in props:
                self.fail(node, "give either 'direction' or 'to_world', not both")
            z = props.get("to_world", np.eye(4))[:3, :3] @ np.array([0.0, 0.0, 1.0])
            d = tf.tamed(props.get("direction", z))
            irradiance, name = props.get("irradiance", np.ones(3)), "irradiance"
            if "to_world" in props:  # Mitsuba lights along to_world's z axis unnormalised: its length scales it
                irradiance = np.asarray(irradiance, dtype=np.float64) * np.hypot.reduce(z)  # (no overflow)
                name = "irradiance times the length of to_world's z axis (which scales Mitsuba's light)"
            e = self.emission(node, name, irradiance)
            if not np.linalg.norm(d) > 0:
                self.fail(node, "a directional emitter needs a non-zero direction")
            builder.add_directional_emitter(e, d)
            return
        allowed = {"intensity": ("rgb", "spectrum", "float"), "to_world": ("transform",), **_SAMPLING_WEIGHT}
        if kind == "point":
            allowed["position"] = ("point",)
        else:
            allowed |= {"cutoff_angle": ("float",), "beam_width": ("float",)}
        props, _ = self.params(node, allowed, unknown=self.textured_emission)
        self.sampling_weight(node, props, delta=True)
        intensity = self.emission(node, "intensity", props.get("intensity", np.ones(3)))
        m = props.get("to_world", np.eye(4))
        if not np.all(m[3] == (0, 0, 0, 1)):
            self.fail(node, "the light's to_world is projective (its last row must be 0 0 0 1)")
        position = props.get("position", m[:3, 3])
        if not np.all(np.abs(position) <= MAX_COORDINATE):
            self.fail(node, f"the light's position {', '.join(f'{x:g}' for x in position)} is beyond ±"
                            f"{MAX_COORDINATE:g} (or not a number): rescale the scene")
        if kind == "point":
            if "position" in props and "to_world" in props:
                self.fail(node, "give either 'position' or 'to_world', not both")
            builder.add_point_emitter(intensity, position)
            return
        cutoff = props.get("cutoff_angle", 20.0)
        beam = props.get("beam_width", 0.75 * cutoff)
        if cutoff > 90.0:
            self.fail(node, f"cutoff_angle {cutoff:g}: a spot wider than a hemisphere (above 90 degrees), which "
                            "Mitsuba renders, is not supported by probvis")
        if not MIN_CUTOFF <= cutoff:
            self.fail(node, f"cutoff_angle must be in [{MIN_CUTOFF:g}, 90] degrees, got {cutoff:g} (a narrower cone "
                            "carries no power in double precision)")
        if not beam >= 0.0:
            self.fail(node, f"beam_width must be at least 0 degrees, got {beam:g}")
        beam = min(beam, cutoff)  # wider: full intensity up to the cutoff, as in Mitsuba's falloff
        axis = tf.tamed(m[:3, :3] @ np.array([0.0, 0.0, 1.0]))
        if not np.linalg.norm(axis) > 0 or not np.all(np.isfinite(axis)):
            self.fail(node, "the spot light's to_world is singular: it maps its +z axis to no direction")
        sig = np.linalg.svd(m[:3, :3], compute_uv=False)
        if sig.min() > 0 and sig.max() - sig.min() > 1e-6 * sig.max():
            warnings.warn(f"{self.where(node)}: the spot light's to_world has a non-uniform scale or a shear, which "
                          "makes its cone elliptical in Mitsuba 3: probvis renders a round cone about its axis; "
                          "scale it uniformly (or not at all)", stacklevel=2)
        builder.add_point_emitter(intensity, m[:3, 3], axis, cutoff, beam)

    def environment(self, node, kind, builder):
        """A top-level `envmap` (image file, scale, to_world) or `constant` (radiance) emitter."""
        if kind == "constant":
            # a to_world, which every Mitsuba emitter reads, turns a constant environment into itself
            props, _ = self.params(node, {"radiance": ("rgb", "spectrum", "float"), "to_world": ("transform",),
                                          **_SAMPLING_WEIGHT}, unknown=self.textured_emission)
            self.sampling_weight(node, props)
            rad = self.emission(node, "radiance", props.get("radiance", np.ones(3)))
            image, m, scale = np.ones((2, 1, 3)), None, rad  # the radiance as the scale: lit points' closed form
        else:
            props, _ = self.params(node, {"filename": ("string",), "scale": ("float",), "to_world": ("transform",),
                                          "mis_compensation": ("boolean",), **_SAMPLING_WEIGHT})
            self.sampling_weight(node, props)
            if "filename" not in props:
                self.fail(node, "envmap needs a 'filename'")
            path = self.input_file(node, props["filename"])
            image = self.image(node, path)
            h, w = image.shape[:2]
            if w < 2 or h < 3:  # as Mitsuba pads a smaller map: its last row and column repeated to 2 x 3
                image = image[np.minimum(np.arange(max(h, 3)), h - 1)][:, np.minimum(np.arange(max(w, 2)), w - 1)]
            if not (np.all(np.isfinite(image)) and image.min() >= 0.0 and image.max() <= MAX_EMISSION):
                self.fail(node, f"{path}: the environment map's values must be finite, non-negative and at most "
                                f"{MAX_EMISSION:g} (they range from {np.nanmin(image):g} to {np.nanmax(image):g})")
            m, scale = props.get("to_world"), props.get("scale", 1.0)
            if m is not None and not np.allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-6):
                self.fail(node, "an envmap's to_world must be a rotation (no scale or shear; a <rotate> about an "
                                "axis not of unit length is neither, as in Mitsuba: give its axis unit length)")
            self.emission(node, "scale", scale)
            if 0.0 < image.max() * scale < 1.0 / MAX_EMISSION:
                self.fail(node, f"scale {scale:g} times the map's largest value {image.max():g} is below "
                                f"{1.0 / MAX_EMISSION:g}: the environment would vanish in single precision")
            if props.get("mis_compensation", False):  # settled once the integrator is read
                self.compensated = node
        try:
            builder.add_environment(image, m, scale, constant=kind == "constant",
                                    mis_compensation=props.get("mis_compensation", False))
        except ProbvisError as exc:
            self.fail(node, str(exc))

    def shape(self, node, builder, outer=None):
        """Add a shape to `builder`; `outer` is an instance's transform, applied after the shape's own."""
        self.check_attrs(node, ("type", "id", "name"))
        kind = self.attr(node, "type")
        if kind == "shapegroup":
            if outer is not None or "id" not in node.attrs:
                self.fail(node, "a shapegroup must be at the top level and have an id")
            _, objs = self.params(node, {}, ("shape",))
            for ch in objs:
                if ch.attrs.get("type") in ("instance", "shapegroup"):
                    self.fail(ch, f"a {ch.attrs['type']} inside a shapegroup (nested instancing) is not supported")
                for em in ch.children:
                    if em.tag == "emitter":  # as Mitsuba's ShapeGroup: an instance's emitter is not sampled
                        self.fail(em, "an emitter inside a shapegroup is not supported (Mitsuba refuses instancing "
                                      "of emitters): give the emitting shape outside the shapegroup")
            self.define(node, "shapegroup", objs)
            return
        if kind == "instance":
            props, objs = self.params(node, {"to_world": ("transform",)}, ("ref",))
            if len(objs) != 1:
                self.fail(node, "an instance needs exactly one <ref> to a shapegroup")
            group = self.resolve(objs[0], "shapegroup")
            m = props.get("to_world", np.eye(4)) if outer is None else outer @ props.get("to_world", np.eye(4))
            if not _invertible_affine(m):  # named here: the group's shapes have transforms of their own
                self.fail(_by_name(node).get("to_world", node), "the instance's to_world is singular or projective (a "
                                                                "scale of 0 flattens it; a matrix's last row must be "
                                                                "0 0 0 1): check its scale and matrix")
            for child in group:
                self.shape(child, builder, m)
            return
        allowed = {"to_world": ("transform",), "flip_normals": ("boolean",)}
        if kind in ("obj", "ply"):
            allowed |= {"filename": ("string",), "face_normals": ("boolean",), "flip_tex_coords": ("boolean",)}
        elif kind == "serialized":
            allowed |= {"filename": ("string",), "face_normals": ("boolean",), "shape_index": ("integer",)}
        elif kind == "sphere":
            allowed |= {"center": ("point",), "radius": ("float",)}
        elif kind == "cylinder":
            allowed |= {"p0": ("point",), "p1": ("point",), "radius": ("float",)}
        elif kind == "cube":  # a mesh in Mitsuba, whose faces are flat already
            allowed |= {"face_normals": ("boolean",)}
        elif kind not in ("rectangle", "disk"):
            self.fail(node, f"unsupported shape type '{kind}' (supported: obj, ply, serialized, rectangle, cube, disk, "
                            "cylinder, sphere, shapegroup, instance)")
        props, objs = self.params(node, allowed, ("bsdf", "ref", "emitter"))
        material, radiance = None, None
        for ch in objs:
            if ch.tag == "emitter":
                if radiance is not None:
                    self.fail(ch, "a shape can carry only one emitter")
                radiance = self.emitter_radiance(ch)
                self.emitter_elements.append((node, ch))
            else:
                key = self.attr(ch, "id", required=False) if ch.tag == "ref" else None
                if key is not None and getattr(self.id_nodes.get(key), "tag", None) == "emitter":
                    self.fail(ch, f"id '{key}' is an <emitter>: a shape's emitter is written inside the shape "
                                  "(<emitter type=\"area\">); a <ref> in a shape names its bsdf")
                if material is not None:
                    self.fail(ch, "a shape can carry only one bsdf")
                refl, two, texture, back = self.bsdf(ch)
                if kind == "cube" and (texture is not None or (back is not None and back[1] is not None)):
                    self.approximate(ch, "texture on a 'cube'", "rendered as its mean colour (probvis gives a "
                                                                "cube no uv)")
                    texture, back = None, back and (back[0], None)  # a textured side's reflectance is its mean
                material = builder.material(refl, two, texture, back)
        if material is None and radiance is not None:  # Mitsuba gives an emitter without a BSDF a black one
            material = builder.material(np.zeros(3))
        m = props.get("to_world", np.eye(4))
        if outer is not None:
            m = outer @ m
        flip = props.get("flip_normals", False)
        face_normals, vnormals, uv = True, None, None
        if kind in ("obj", "ply", "serialized"):
            fname = props.get("filename")
            if fname is None:
                self.fail(node, "missing 'filename'")
            mesh_path = self.input_file(node, fname)
            if not mesh_path.exists():
                self.fail(node, missing_file(mesh_path, "mesh file"))
            if not mesh_path.is_file():
                self.fail(node, f"mesh {mesh_path} is not a regular file (a mesh is an OBJ, PLY or serialized file)")
            try:
                if kind == "serialized":
                    v, f, vnormals, uv = load_serialized(mesh_path, props.get("shape_index", 0))
                else:
                    v, f, vnormals, uv = shp.load_mesh(mesh_path, props.get("flip_tex_coords"), kind)
            except ProbvisError as exc:
                self.fail(node, str(exc))
            face_normals = props.get("face_normals", False)
        elif kind == "rectangle":
            v, f = shp.rectangle()
            uv = 0.5 * (v[:, :2] + 1.0)  # Mitsuba's: 0 to 1 along x and y
        elif kind == "cube":
            v, f = shp.cube()
        elif kind == "disk":
            v, f = shp.disk()
        elif kind == "cylinder":
            v, f, vnormals = shp.cylinder()
            frame = self.cylinder_frame(node, props)
            if frame is None:
                self.left_out(node, kind, radiance, "its radius is 0 or p0 = p1")
                return
            m = m @ frame
            face_normals = False
        else:
            v, f, vnormals = shp.uv_sphere()
            r = props.get("radius", 1.0)
            if not abs(r) <= MAX_COORDINATE:  # negative: turned inside out, as Mitsuba flips its normals
                self.fail(node, f"sphere radius must be at most {MAX_COORDINATE:g} in size, got {r:g}")
            if r == 0:
                self.left_out(node, kind, radiance, "its radius is 0")
                return
            m = self.round_sphere(node, m @ tf.translate(props.get("center", np.zeros(3))) @ tf.scale([r, r, r]))
            face_normals = False
        if kind in ("disk", "sphere", "cylinder"):
            uv = shp.analytic_uv(kind, v[f])
        if not _invertible_affine(m):
            self.fail(node, "the shape's to_world is singular or projective (a scale of 0 flattens it; a matrix's "
                            "last row must be 0 0 0 1): check its scale and matrix")
        # Which side faces out under a mirroring transform, as in Mitsuba: an instance's mirror never turns a
        # shape inside out (normals go by its inverse transpose), so the winding it reverses is reversed back; a
        # shape's own mirror turns meshes and spheres inside out, not the other analytic shapes (Mitsuba's cube
        # is a mesh with its own normals). The vertex normals given with a sphere or cylinder are transformed as
        # normals, so their winding alone is reversed back (and a sphere's flipped with its normals)
        outer_mirror = outer is not None and np.linalg.det(outer[:3, :3]) < 0
        own_mirror = (np.linalg.det(m[:3, :3]) < 0) != outer_mirror
        if kind in ("rectangle", "cube", "disk", "sphere") and own_mirror:
            flip = not flip
        if kind == "cylinder" and own_mirror and radiance is not None:
            warnings.warn(f"{self.where(node)}: a cylinder emitter under a mirroring to_world emits here as the "
                          "unmirrored one; Mitsuba 3 splits its light between its sides (less outward, some inward "
                          "even with flip_normals): to match it, leave the mirror out", stacklevel=2)
        if outer_mirror != (kind in ("cylinder", "sphere") and own_mirror):
            f = f[:, ::-1]
            if uv is not None and np.ndim(uv) == 3:
                uv = uv[:, ::-1]
        name = self.attr(node, "id", f"{kind}@{node.line}")
        try:
            kept = builder.add_mesh(name, kind, v, f, m, material, radiance, face_normals, vnormals, flip, uv)
        except ProbvisError as exc:
            self.fail(node, str(exc))
        if kept == 0:
            self.left_out(node, kind, radiance, f"all {len(f)} of its triangles are degenerate once transformed")

    def left_out(self, node, kind, radiance, why):
        """A shape without area is left out with a warning, as Mitsuba renders nothing of it. One with an area
        emitter, which emits nothing, is judged once the scene is read (`dark_emitters`)."""
        if radiance is not None:
            self.dark.append((node, kind, why))
            return
        warnings.warn(f"{self.where(node)}: shape '{kind}' has no area ({why}): it is left out; check its size and "
                      "to_world", stacklevel=3)

    def dark_emitters(self, builder):
        """Area emitters on shapes without area: left out with a warning where other emitters light the scene,
        as Mitsuba renders it; refused at the first one's element where none does."""
        if not self.dark:
            return
        if not builder.emitter_radiance:
            first, _, why = self.dark[0]
            self.fail(first, f"an area emitter on a shape without area ({why}) emits nothing, and the scene has no "
                             "other emitter: check the shape's size and to_world")
        for node, kind, why in self.dark:
            warnings.warn(f"{self.where(node)}: shape '{kind}' has no area ({why}): it is left out with its area "
                          "emitter, which emits nothing; check its size and to_world", stacklevel=3)

    def zero_power(self, builder):
        """Emitters that all emit nothing (a radiance, intensity or scale of 0) are refused at the first one's
        element: there is nothing to sample by power, and Mitsuba renders the scene black."""
        if builder.emitter_radiance and not np.any(np.array(builder.emitter_radiance)):
            left_out = {id(shape) for shape, _, _ in self.dark}  # without area: not among the scene's emitters
            first = next((e for shape, e in self.emitter_elements if shape is None or id(shape) not in left_out),
                         self.emitter_elements[0][1])
            n = len(builder.emitter_radiance)
            self.fail(first, f"the scene's {n} emitter{'s all have' if n > 1 else ' has'} zero power (a radiance, "
                             "intensity or irradiance of 0, or a scale of 0): the image would be black (as Mitsuba "
                             "renders it); give an emitter a positive one")

    def unsampled_emitters(self):
        """Emitters of sampling_weight 0, which Mitsuba's emitter sampling never picks: refused at the first when
        no emitter has a positive weight (Mitsuba cannot load such a scene), else each left aside with a warning
        that says whether Mitsuba's image has their light (found by BSDF sampling) or lacks it (bsdf_samples 0).
        Positive weights, left aside too, are said once for all the emitters that have one."""
        if self.weighted:
            n = len(self.weighted) - 1
            more = f" (and on {n} more emitter{'s' if n > 1 else ''})" if n else ""
            warnings.warn(f"{self.where(self.weighted[0])}: sampling_weight ignored{more}: probvis samples emitters "
                          "by their power (the same expected image)", stacklevel=3)
        if not self.unweighted:
            return
        if not self.sampled:
            self.fail(self.unweighted[0], "every emitter has sampling_weight 0: Mitsuba 3 cannot load such a scene "
                                          "(no emitter to sample); give one a positive weight")
        for node in self.unweighted:
            if self.bsdf_samples > 0:
                warnings.warn(f"{self.where(node)}: sampling_weight 0 ignored: Mitsuba finds this emitter by BSDF "
                              "sampling alone; probvis samples emitters by their power (the same expected image)",
                              stacklevel=3)
            else:
                warnings.warn(f"{self.where(node)}: sampling_weight 0 with bsdf_samples 0: Mitsuba never samples "
                              "this emitter and its image lacks the emitter's light on the scene; probvis samples "
                              "emitters by their power and renders that light (give bsdf_samples 1 for Mitsuba's "
                              "image to have it too)", stacklevel=3)

    def compensated_environment(self, builder):
        """An envmap's mis_compensation, once the integrator is known. With BSDF samples, Mitsuba's multiple
        importance sampling finds the dimmer directions' light by BSDF sampling, so its image has the whole map's
        light: probvis, which samples no BSDF, samples the whole map (the same expected image). Without them that
        light is missing from Mitsuba's image: sampled as Mitsuba does, and said."""
        if self.compensated is None:
            return
        if self.bsdf_samples > 0:
            builder.environment.mis_compensation = False
            return
        warnings.warn(f"{self.where(self.compensated)}: mis_compensation samples the map by its luminance less the "
                      "mean, leaving the dimmer directions to BSDF sampling, which `direct` with bsdf_samples 0 does "
                      "not do: their light is missing, in Mitsuba as here; leave it out, or give bsdf_samples 1, for "
                      "all of it", stacklevel=3)

    def cylinder_frame(self, node, props):
        """Object-to-shape transform of Mitsuba's cylinder from p0 to p1 with a radius (the unit cylinder's z
        axis along p1 - p0, x and y as Mitsuba's frame of that axis). A negative radius turns the frame half a
        turn about the axis, as Mitsuba's scale by it does: the same surface, facing out. None for a cylinder
        without area (radius 0, p0 = p1)."""
        p0, p1 = props.get("p0", np.zeros(3)), props.get("p1", np.array([0.0, 0.0, 1.0]))
        r = props.get("radius", 1.0)
        for name, p in (("p0", p0), ("p1", p1)):
            if not np.all(np.abs(p) <= MAX_COORDINATE):
                self.fail(node, f"a cylinder's {name} ({', '.join(f'{v:g}' for v in p)}) lies beyond "
                                f"±{MAX_COORDINATE:g}: rescale the scene")
        if not abs(r) <= MAX_COORDINATE:
            self.fail(node, f"a cylinder's radius must be at most {MAX_COORDINATE:g} in size, got {r:g}: rescale the "
                            "scene")
        axis = np.asarray(p1, float) - np.asarray(p0, float)
        length = float(np.linalg.norm(axis))
        if not (r != 0 and length > 0):
            return None
        if (length / abs(r) if abs(r) >= length else (r / length) ** 2) < 1e-12:
            self.fail(node, f"a cylinder of radius {r:g} from p0 to p1 {length:g} apart is too "
                            f"{'flat' if abs(r) >= length else 'thin'} to hold any area in double precision: move p0 "
                            "and p1 apart or change the radius")
        z = axis / length
        x, y = tf.coordinate_system(z)  # Mitsuba's Frame3f(z), which fixes where the uv's phi starts
        frame = np.eye(4)
        frame[:3, 0], frame[:3, 1], frame[:3, 2], frame[:3, 3] = x * r, y * r, z * length, p0
        return frame

    def sensor(self, node):
        self.check_attrs(node, ("type", "id", "name"))
        kind = self.attr(node, "type")
        if kind not in ("perspective", "thinlens"):
            self.fail(node, f"unsupported sensor type '{kind}' (supported: perspective, thinlens)")
        allowed = {"fov": ("float",), "focal_length": ("string",), "fov_axis": ("string",),
                   "to_world": ("transform",), "near_clip": ("float",), "far_clip": ("float",),
                   "srf": ("spectrum", "rgb"), "shutter_open": ("float",), "shutter_close": ("float",)}
        if kind == "perspective":  # focus_distance is read by every projective camera; a pinhole ignores it
            allowed.update(principal_point_offset_x=("float",), principal_point_offset_y=("float",),
                           focus_distance=("float",))
        else:
            allowed.update(aperture_radius=("float",), focus_distance=("float",))
        props, objs = self.params(node, allowed, ("sampler", "film"))
        if props.get("shutter_open", 0.0) > props.get("shutter_close", 0.0):  # Mitsuba's defaults: both 0
            self.fail(_by_name(node)["shutter_open"], "shutter_open must not be after shutter_close (as Mitsuba "
                                                      "requires; nothing moves in a probvis scene, so neither matters)")
        if "srf" in props:
            if np.any(np.asarray(props["srf"]) < 0):
                self.fail(node, "the sensor's srf (spectral response) must not be negative")
            self.approximate(node, "sensor 'srf'", "ignored: probvis renders RGB with the standard response")
        spp, seed, film, sampler = 4, 0, None, None  # Mitsuba's default sample count and seed
        for ch in objs:
            if ch.tag == "sampler":
                if sampler is not None:
                    self.fail(ch, "only one sampler per sensor")
                sampler = ch
                self.check_attrs(ch, ("type", "id", "name"))
                st = self.attr(ch, "type")
                if st not in _SAMPLERS:
                    self.fail(ch, f"unsupported sampler type '{st}'")
                if st != "independent":
                    warnings.warn(f"{self.where(ch)}: sampler '{st}' rendered with probvis's independent "
                                  "sampler (same expected image, different noise)", stacklevel=2)
                lines = _by_name(ch)
                sp, _ = self.params(ch, {"sample_count": ("integer",), "seed": ("integer",),
                                         **{name: ("integer",) if name == "strength" else ("boolean",)
                                            for name in _SAMPLERS[st]}})
                spp, seed = sp.get("sample_count", spp), sp.get("seed", seed)
                for name, value, lo, hi in (("sample_count", spp, 1, MAX_SPP), ("seed", seed, 0, MAX_SAMPLER_SEED)):
                    if not lo <= value <= hi:
                        self.fail(lines.get(name, ch), f"{name} must be from {lo} to {hi}, got {value}")
            else:
                if film is not None:
                    self.fail(ch, "only one film per sensor")
                film = self.film(ch)
        film = film or self.film(None)
        fw, fh = film["film_width"], film["film_height"]
        fov_x, axis = self.fov_x(node, props, fw / fh)
        near, far = props.get("near_clip", 1e-2), props.get("far_clip", 1e4)
        lens = {}
        if kind == "thinlens":
            if "aperture_radius" not in props:
                self.fail(node, "a thinlens sensor needs 'aperture_radius'")
            # Mitsuba scales its unit-disk sample by the radius as given: a negative one is the same disk
            lens = {"aperture_radius": abs(props["aperture_radius"]),
                    "focus_distance": props.get("focus_distance", far)}
            if not lens["focus_distance"] > 0:
                self.fail(node, "focus_distance must be positive")
        m = props.get("to_world", np.eye(4))
        if not _invertible_affine(m):
            self.fail(node, "the sensor's to_world is singular or projective: a camera needs a rotation and a "
                            "translation (check its scale and matrix)")
        cam = Camera(m, fov_x, near_clip=near, far_clip=far, fov_axis=axis,
                     principal_x=props.get("principal_point_offset_x", 0.0),
                     principal_y=props.get("principal_point_offset_y", 0.0), **lens, **film)
        if problem := camera_problem(cam):
            self.fail(node, problem)
        return cam, spp, seed

    def fov_x(self, node, props, aspect):
        """The horizontal field of view, from `fov` along `fov_axis` or from a 35 mm `focal_length` (as Mitsuba's
        parse_fov: the focal length spans the 36 x 24 mm frame's diagonal; default 50 mm), and that axis."""
        if "fov" in props and "focal_length" in props:
            self.fail(node, "give either 'fov' or 'focal_length', not both")
        if "fov_axis" in props and "fov" not in props:  # unreferenced in Mitsuba, which refuses it
            self.fail(node, "fov_axis applies to 'fov' only (a focal_length spans the 35 mm frame's diagonal): give "
                            "fov, or drop fov_axis")
        if "fov" in props:
            fov = props["fov"]
            axis = props.get("fov_axis", "x").lower()
        else:
            text = str(props.get("focal_length", "50mm")).strip()
            try:
                f = _float(text[:-2] if text.endswith("mm") else text)
            except ValueError:
                self.fail(node, f"focal_length must be of the form <x>mm, got '{text}'")
            if not f > 0 or not np.isfinite(f):
                self.fail(node, f"focal_length must be positive, got '{text}'")
            with np.errstate(over="ignore"):  # a tiny focal length: an infinite ratio, a view 180 degrees wide
                fov = float(np.degrees(2.0 * np.arctan(np.hypot(36.0, 24.0) / (2.0 * np.float64(f)))))
            axis = "diagonal"
        if not 0.0 < fov < 180.0:
            if "fov" in props:
                self.fail(node, f"fov must be between 0 and 180 degrees, got {fov:g}")
            self.fail(node, f"focal_length {props['focal_length']} makes the view {fov:.10g} degrees wide (at most "
                            f"{MAX_FOV:g}: wider, a perspective image shrinks the whole scene to a few pixels at its "
                            "centre)")
        if axis not in FOV_AXES:
            self.fail(node, f"unknown fov_axis '{axis}' ({', '.join(FOV_AXES)})")
        fov_x = float(np.degrees(2.0 * np.arctan(np.tan(np.radians(fov) / 2.0) * tan_x_per_axis(axis, aspect))))
        fov_y = float(np.degrees(2.0 * np.arctan(np.tan(np.radians(fov_x) / 2.0) / aspect)))
        if max(fov_x, fov_y) > MAX_FOV + FOV_ROUNDING:
            given = f"fov {fov:.10g}" if "fov" in props else f"focal_length {props.get('focal_length')}"
            across, more = (f"{fov_x:.10g} degrees wide", "wider") if fov_x >= fov_y else \
                (f"{fov_y:.10g} degrees tall", "taller")
            self.fail(node, f"{given} makes the view {across} (at most {MAX_FOV:g}: {more}, a perspective image "
                            "shrinks the whole scene to a few pixels at its centre)")
        return fov_x, axis

    def film(self, node):
        """The film's size, crop window and reconstruction filter as `Camera` fields (Mitsuba's defaults
        without a <film>: 768 x 576, Gaussian filter)."""
        width, height, rfilter = 768, 576, {"rfilter": "gaussian"}
        props = {}
        if node is not None:
            self.check_attrs(node, ("type", "id", "name"))
            kind = self.attr(node, "type")
            if kind != "hdrfilm":
                self.fail(node, f"unsupported film type '{kind}' (supported: hdrfilm)")
            props, objs = self.params(
                node, {"width": ("integer",), "height": ("integer",), "pixel_format": ("string",),
                       "component_format": ("string",), "file_format": ("string",), "crop_offset_x": ("integer",),
                       "crop_offset_y": ("integer",), "crop_width": ("integer",), "crop_height": ("integer",),
                       "sample_border": ("boolean",), "banner": ("boolean",), "compensate": ("boolean",)},
                ("rfilter",))
            if props.get("sample_border", False):
                self.fail(_by_name(node)["sample_border"], "sample_border is not supported: probvis samples the "
                          "image's own pixels only, so the light a wide filter brings in from beyond the border would "
                          "be missing (drop it, or render a larger film and crop it)")
            for key, known in (("pixel_format", ("rgb", "rgba", "luminance", "luminance_alpha", "xyz", "xyza")),
                               ("component_format", ("float16", "float32", "uint32")),
                               ("file_format", ("openexr", "exr", "rgbe", "hdr", "pfm"))):
                if props.get(key, known[0]).lower() not in known:
                    self.fail(node, f"unknown {key} '{props[key]}' (Mitsuba's hdrfilm takes {', '.join(known)})")
            written = (("pixel_format", ("rgb",)), ("component_format", ("float16", "float32")),
                       ("file_format", ("openexr", "exr")))  # what Mitsuba writes by default, and probvis
            unused = [f"{key} '{props[key]}'" for key, same in written if props.get(key, same[0]).lower() not in same]
            if unused:
                warnings.warn(f"{self.where(node)}: hdrfilm's {' and '.join(unused)} not used: probvis writes RGB "
                              "float32 images in the format of the output's extension (-o out.exr, .pfm, .png)",
                              stacklevel=2)
            for k, ch in enumerate(objs):
                if k:
                    self.fail(ch, "only one reconstruction filter per film")
                rfilter = self.rfilter(ch)
            width, height = props.get("width", width), props.get("height", height)
            if width < 1 or height < 1 or width > MAX_FILM_EXTENT or height > MAX_FILM_EXTENT:
                self.fail(node, f"film size {width}x{height} is out of range (1 to {MAX_FILM_SIDE}, or to "
                                f"{MAX_FILM_EXTENT} with a smaller crop window)")
        cx, cy = props.get("crop_offset_x", 0), props.get("crop_offset_y", 0)
        cw, ch_ = props.get("crop_width", width), props.get("crop_height", height)  # Mitsuba's defaults
        if not (0 <= cx and cw >= 1 and cx + cw <= width and 0 <= cy and ch_ >= 1 and cy + ch_ <= height):
            self.fail(node, f"the crop window {cw}x{ch_} at ({cx}, {cy}) does not fit the {width}x{height} film")
        if cw > MAX_FILM_SIDE or ch_ > MAX_FILM_SIDE:  # what is rendered; a larger film sets only the projection
            cropped = cw != width or ch_ != height
            self.fail(node, f"{'the crop window' if cropped else 'film size'} {cw}x{ch_} is out of range (1 to "
                            f"{MAX_FILM_SIDE}){'' if cropped else ': render it in crop windows'}")
        return {"width": cw, "height": ch_, "film_width": width, "film_height": height, "crop_x": cx, "crop_y": cy,
                **rfilter}

    def rfilter(self, node):
        self.check_attrs(node, ("type", "name", "id"))
        kind = self.attr(node, "type")
        if kind == "box":
            self.params(node, {})
            return {"rfilter": "box"}
        if kind in ("mitchell", "catmullrom"):  # Mitsuba's B and C, 1/3 by default; Catmull-Rom's fixed
            props, _ = self.params(node, {"B": ("float",), "C": ("float",)} if kind == "mitchell" else {})
            b, c = props.get("B", 1.0 / 3.0), props.get("C", 1.0 / 3.0)
            if not (abs(b) <= MAX_CUBIC_PARAMETER and abs(c) <= MAX_CUBIC_PARAMETER):
                self.fail(node, f"a mitchell filter's B and C must be within ±{MAX_CUBIC_PARAMETER:g}, got {b:g} and "
                                f"{c:g} (1/3 each by default)")
            if not (0.0 <= b <= 1.0 and 0.0 <= c <= 1.0):  # Mitchell and Netravali's family lies in [0, 1]²
                warnings.warn(f"{self.where(node)}: a mitchell filter with B {b:g} and C {c:g}, outside 0 to 1: its "
                              "lobes ring around every edge (as in Mitsuba); 1/3 each is the default", stacklevel=2)
            return {"rfilter": kind, "filter_b": b, "filter_c": c} if kind == "mitchell" else {"rfilter": kind}
        if kind == "lanczos":
            props, _ = self.params(node, {"lobes": ("integer",)})
            lobes = props.get("lobes", 3)
            if not 1 <= lobes <= MAX_FILTER_RADIUS:
                self.fail(node, f"a lanczos filter's lobes must be from 1 to {MAX_FILTER_RADIUS:g}, got {lobes}")
            return {"rfilter": kind, "filter_radius": float(lobes)}
        # Mitsuba's parameter of each filter, its default, and the Camera field it sets
        known = {"tent": ("radius", 1.0, "filter_radius"), "gaussian": ("stddev", 0.5, "filter_stddev")}
        if kind not in known:
            self.fail(node, f"unsupported rfilter '{kind}' (supported: {', '.join(FILTERS)})")
        name, default, field_name = known[kind]
        props, _ = self.params(node, {name: ("float",)})
        value = props.get(name, default)
        most = MAX_FILTER_RADIUS if kind == "tent" else MAX_FILTER_RADIUS / 4  # a Gaussian reaches 4 stddev
        if not 0 < value <= most:
            self.fail(node, f"{kind} {name} must be positive and at most {most:g} pixels, got {value:g}")
        reach = value if kind == "tent" else 4 * value  # a Gaussian reaches 4 stddev
        counted = min(1.0, 2 * reach) ** 2  # within `reach` of a pixel centre on both axes: (2 reach)² of them
        if reach < MIN_FILTER_REACH:
            self.fail(node, f"{kind} {name} {value:g} reaches {reach:g} pixels: only {counted:.2g} of the camera "
                            f"samples would reach a pixel centre and count (use at least "
                            f"{MIN_FILTER_REACH if kind == 'tent' else MIN_FILTER_REACH / 4:g}, or a box filter)")
        if counted < 1.0:  # as in Mitsuba: the image divides by the weights the samples that count bring
            warnings.warn(f"{self.where(node)}: {kind} {name} {value:g} reaches {reach:g} pixels: splatted, "
                          f"{counted:.1%} of the camera samples reach a pixel centre and count (as in Mitsuba), so the "
                          "image is noisier than a box filter's", stacklevel=2)
        return {"rfilter": kind, field_name: value}

    def integrator(self, node):
        self.check_attrs(node, ("type", "id", "name"))
        kind = self.attr(node, "type")
        if kind in ("path", "volpath"):
            props, _ = self.params(node, {"max_depth": ("integer",), "rr_depth": ("integer",),
                                          "hide_emitters": ("boolean",)})
            self.hide_emitters = props.get("hide_emitters", False)
            depth = props.get("max_depth", -1)
            if depth < -1:
                self.fail(node, f"max_depth must be -1 (no limit) or at least 2 here, got {depth}")
            if props.get("rr_depth", 5) <= 0:  # unused by direct illumination, refused as Mitsuba does
                self.fail(node, f"rr_depth must be positive, got {props['rr_depth']}")
            if depth in (0, 1):  # Mitsuba: 0 renders nothing, 1 only the emitters seen directly
                lost = "no light" if depth == 0 else "no direct illumination"
                self.fail(node, f"max_depth {depth} renders {lost} in Mitsuba; probvis renders direct illumination "
                                "(max_depth 2, or a 'direct' integrator)")
            warnings.warn(f"{self.where(node)}: integrator '{kind}' rendered as its direct-illumination "
                          "component (probvis renders direct illumination only; one emitter sample per camera "
                          "sample unless --shadow-rays says otherwise)", stacklevel=2)
            return 1
        if kind != "direct":
            self.fail(node, f"unsupported integrator '{kind}' (supported: direct; path and volpath as their direct "
                            "illumination)")
        props, _ = self.params(node, {"emitter_samples": ("integer",), "bsdf_samples": ("integer",),
                                      "shading_samples": ("integer",), "hide_emitters": ("boolean",)})
        self.hide_emitters = props.get("hide_emitters", False)  # emitters are not seen directly
        lines = _by_name(node)
        both = [k for k in ("emitter_samples", "bsdf_samples") if k in props]
        if "shading_samples" in props and both:  # Mitsuba refuses the pair: which one counts would be a guess
            self.fail(lines[both[0]], f"give either shading_samples or {' and '.join(both)}, not both (as Mitsuba "
                                      "requires)")
        base = props.get("shading_samples", 1)
        if not 1 <= base <= MAX_SHADOW_RAYS:
            self.fail(lines.get("shading_samples", node), f"shading_samples must be from 1 to {MAX_SHADOW_RAYS}, "
                                                          f"got {base}")
        if props.get("bsdf_samples", 0) < 0:
            self.fail(lines["bsdf_samples"], f"bsdf_samples must not be negative, got {props['bsdf_samples']}")
        self.bsdf_samples = props.get("bsdf_samples", base)
        sr = props.get("emitter_samples", base)
        if not 1 <= sr <= MAX_SHADOW_RAYS:
            self.fail(lines.get("emitter_samples", node), f"emitter_samples must be from 1 to {MAX_SHADOW_RAYS}, "
                                                          f"got {sr} (probvis samples emitters only)")
        if props.get("bsdf_samples", 0) != 0:  # only when the file asks for them: a default is no request
            warnings.warn(f"{self.where(node)}: bsdf_samples ignored: probvis samples emitters only "
                          "(same expected image)", stacklevel=2)
        return sr

    def round_sphere(self, node, m):
        """A sphere's transform as Mitsuba takes it: a non-uniform scale or a shear gives not an ellipsoid but a
        round sphere (Mitsuba warns), of the radius the transform's stretch gives its x axis once the rotation is
        taken out (the polar decomposition m = rotation @ stretch). A singular or projective one is left to be
        refused."""
        if not _invertible_affine(m):
            return m
        u, sig, vt = np.linalg.svd(m[:3, :3])
        stretch = vt.T @ np.diag(sig) @ vt
        radius = stretch[0, 0]
        if np.allclose(stretch, radius * np.eye(3), rtol=0.0, atol=1e-6 * sig.max()):
            return m
        warnings.warn(f"{self.where(node)}: the sphere's to_world has a non-uniform scale or a shear: rendered "
                      f"round, of radius {radius:.6g}, as Mitsuba renders it (an ellipsoid is a mesh: obj or ply)",
                      stacklevel=2)
        out = m.copy()
        out[:3, :3] = (u @ vt) * radius
        return out

    def _search_path(self, node):
        """A `<path>` folder, searched for every file the scene names (wherever the element stands, as in Mitsuba;
        one made of parameters from where it stands), the latest first as Mitsuba's resolver prepends them, then
        the scene's folder."""
        self.check_attrs(node, ("value",))
        folder = self.path.parent / self.attr(node, "value")
        if not folder.is_dir():
            self.fail(node, f"folder '{folder}' not found (a <path> names a folder searched for files)")
        self.search_paths.insert(0, folder)

    def input_file(self, node, name):
        """The file a scene parameter names, relative to the scene file's folder, recorded among the inputs."""
        if not name.strip():
            self.fail(node, "the filename is empty")
        path = Path(name) if Path(name).is_absolute() else self.path.parent / name
        try:  # a folder the process may not search makes exists() raise: named here, at the element
            if not Path(name).is_absolute():
                path = next((folder / name for folder in self.search_paths if (folder / name).exists()), path)
            path.exists()
        except OSError as exc:
            self.fail(node, f"cannot read {path}: {exc.strerror or exc}")
        self.inputs.append(path)
        return path

    def default_value(self, node, name):
        """A `<default>`'s value: as written where -D gives the parameter (its `$b` then needs no other), else
        with the parameters known so far substituted."""
        return node.attrs["value"] if name in self.overrides else self.attr(node, "value")

    def _include_name(self, node, defaults):
        """An `<include>`'s file name with its parameters substituted, as Mitsuba does: -D values, then the
        `<default>` elements above it (the first of a name kept)."""
        saved, self.defaults = self.defaults, {}
        try:
            for d in defaults:
                name = d.attrs.get("name")
                if name and name not in self.defaults and "value" in d.attrs:
                    self.defaults[name] = self.default_value(d, name)
            return self.attr(node, "filename")
        finally:
            self.defaults = saved

    def read(self):
        self.root = root = parse_tree(self.path)
        if root.tag != "scene":
            self.fail(root, "the root element must be <scene>")
        with_includes(root, self.path, self.fail, self._include_name)
        self.inputs += list(dict.fromkeys(n.file for n in _document_order(root) if n.file is not None))
        self.check_attrs(root, ("version",))
        if "version" in root.attrs and not re.fullmatch(r"\d+\.\d+\.\d+", root.attrs["version"].strip()):
            self.fail(root, f"version must be a version number of three parts such as 3.0.0 (as Mitsuba requires), "
                            f"got '{root.attrs['version']}'")
        if int(root.attrs.get("version", "3").strip().split(".")[0]) < 2:  # its errors say which format it is in
            self.old_version = root.attrs["version"].strip()
        self.id_nodes = _unique_ids(root, self.fail, self.line_of)
        for ch in root.children:
            if ch.tag == "path" and "$" not in ch.attrs.get("value", ""):
                self._search_path(ch)
        builder = SceneBuilder(self.path.stem, str(self.path))
        camera, spp, seed, shadow_rays = None, 4, 0, 1
        integrator_line = None
        for ch in root.children:
            if ch.tag == "default":
                self.declare_default(ch)
            elif ch.tag == "integrator":
                if integrator_line is not None:
                    self.fail(ch, f"only one integrator per scene (the first on line {integrator_line})")
                integrator_line = ch.line
                shadow_rays = self.integrator(ch)
            elif ch.tag == "sensor":
                first = self.sensor(ch)  # every sensor is read and checked, as Mitsuba loads them all
                if camera is not None:
                    warnings.warn(f"{self.where(ch)}: a second <sensor>: probvis renders the first, as Mitsuba does "
                                  "by default", stacklevel=2)
                    continue
                camera, spp, seed = first
            elif ch.tag in ("bsdf", "texture"):
                if "id" not in ch.attrs:
                    self.fail(ch, f"a top-level {ch.tag} needs an 'id'")
                if self.id_defined.get(self.attr(ch, "id")) is not ch:  # not read ahead for a <ref> above it
                    self.bsdf(ch) if ch.tag == "bsdf" else self.texture(ch)
            elif ch.tag == "shape":
                self.shape(ch, builder)
            elif ch.tag == "emitter":
                self.delta_emitter(ch, builder)
                self.emitter_elements.append((None, ch))
            elif ch.tag == "alias":
                self.check_attrs(ch, ("id", "as"))
                source = self.attr(ch, "id")
                target = self.id_nodes.get(source)
                if target is None:
                    self.fail(ch, f"alias of unknown id '{source}'")
                if source in self.ids:
                    self.define(ch, self.ids[source][0], self.ids[source][1], key=self.attr(ch, "as"))
                elif target.order > ch.order:
                    self.fail(ch, f"id '{source}' is defined after this alias ({self.line_of(target, ch)}): move it "
                                  "above")
                # else an object nothing can refer to (a shape, an emitter): its alias names nothing usable
            elif ch.tag == "path":
                if "$" in ch.attrs.get("value", ""):  # the others were read before the rest
                    self._search_path(ch)
            elif ch.tag == "include":
                self.fail(ch, "<include> is not supported by probvis: paste the included file's elements here")
            else:
                self.fail(ch, "unsupported element")
        for key, (kind, shapes) in list(self.ids.items()):  # Mitsuba loads a group's shapes though none uses it
            if kind == "shapegroup" and key not in self.referenced:
                for child in shapes:
                    self.shape(child, SceneBuilder(key, str(self.path)), np.eye(4))
        if camera is None:
            self.fail(self.root, "the scene has no <sensor>: add one (a <sensor type=\"perspective\"> with its "
                                 "to_world and film) to render it or list it; Mitsuba renders none without one either")
        unused = sorted(set(self.overrides) - self.used - set(self.defaults))
        if unused:
            flags = [f"--{n.replace('_', '-')} {self.overrides[n]}" for n in unused
                     if n in ("spp", "shadow_rays", "seed")]  # the render's settings, which the command sets
            warnings.warn(f"{self.path}: -D {', '.join(unused)}: the scene declares no such parameter "
                          f"(its parameters: {', '.join(sorted(self.defaults)) or 'none'})"
                          + (f"; for the render's own setting give {' '.join(flags)}" if flags else ""), stacklevel=2)
        unread = sorted(set(self.overrides) - self.used - set(unused))
        if unread:  # Mitsuba refuses them ("unused parameters"); the scene renders as written
            warnings.warn(f"{self.path}: -D {', '.join(unread)}: the scene declares "
                          f"{'it' if len(unread) == 1 else 'them'} but no value reads "
                          f"{'it' if len(unread) == 1 else 'them'} ($name reads the longest declared name), so the "
                          "image is the same without", stacklevel=2)
        builder.inputs = tuple(dict.fromkeys(Path(os.path.realpath(p)) for p in self.inputs))
        builder.hide_emitters = self.hide_emitters
        builder.parameters = tuple(sorted(self.defaults))
        self.dark_emitters(builder)
        self.zero_power(builder)
        self.unsampled_emitters()
        self.compensated_environment(builder)
        deltas = [kind for kind, *_ in builder.deltas.values() if kind != EMITTER_ENVIRONMENT]
        if shadow_rays > 1 and deltas:  # see docs/decisions.md, "Where Mitsuba 3.9 is not followed"
            warnings.warn(f"{self.path}:{integrator_line}: emitter_samples {shadow_rays} with point, spot or "
                          f"directional lights: Mitsuba 3.9 renders those lights {shadow_rays} times too bright (its "
                          "delta lights' samples lack the 1/N); probvis renders their true light, Mitsuba's image at "
                          "emitter_samples 1", stacklevel=2)
        try:
            return builder.build(camera, RenderSettings(spp, shadow_rays, seed))
        except ProbvisError as exc:
            raise ProbvisError(f"{self.path}: {exc}") from None


def read_scene(path, strict=False, overrides=None):
    """Load a Mitsuba 3 XML scene; `overrides` (a dict) replace `<default>` values as `-D name=value` does.
    Appearance that probvis approximates (non-diffuse BSDFs) is a warning, or with `strict` an error."""
    overrides = overrides or {}
    return _Reader(path, overrides, strict).read()
