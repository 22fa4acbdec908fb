"""The sensor a scene declares: Mitsuba's perspective or thin-lens camera with its film (`Camera`), and what
makes one unusable (`camera_problem`)."""
import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..errors import is_number

MAX_FILM_SIDE = 1 << 15  # pixels along the side of the image rendered (the film, or its crop window)
MAX_FILM_EXTENT = 1 << 24  # pixels along a cropped film's side: it sets only the projection
MAX_FILTER_RADIUS = 32.0  # pixels a film's reconstruction filter may reach (splatting cost grows with its square)
MIN_FILTER_REACH = 0.01  # pixels: a tent or 4σ below this counts fewer than 1 in 2,500 of the samples
FILTERS = ("box", "tent", "gaussian", "mitchell", "catmullrom", "lanczos")  # Mitsuba 3's reconstruction filters
MAX_CUBIC_PARAMETER = 100.0  # |B|, |C| of a mitchell filter: its weights grow with them (1/3 by default)
MAX_PRINCIPAL_OFFSET = 1e3  # film sizes: beyond, the view's axis is within a thousandth of a radian of the film plane
MAX_FOV = 179.5  # degrees across the film: wider, a perspective image shrinks the scene to a few pixels at its centre
FOV_ROUNDING = 1e-9  # degrees: a view declared along y at the limit comes back from x a few ulps above it
MAX_APERTURE_RATIO = 1e3  # lens radius per focus distance: beyond, every ray leaves the lens nearly along its plane
FOV_AXES = ("x", "y", "diagonal", "smaller", "larger")  # what a field of view may span (Mitsuba's fov_axis)
MAX_CAMERA_SCALE = 1e-3  # Mitsuba refuses a camera whose to_world's M M^T is further than this from the identity


def tan_x_per_axis(axis, aspect):
    """tan(fov_x / 2) per tan(fov / 2) for a field of view spanning `axis` (`FOV_AXES`) of a film of `aspect`
    (width / height), as Mitsuba's parse_fov converts it."""
    if axis == "smaller":
        axis = "y" if aspect > 1 else "x"
    elif axis == "larger":
        axis = "x" if aspect > 1 else "y"
    return {"x": 1.0, "y": aspect, "diagonal": 1.0 / math.sqrt(1.0 + 1.0 / (aspect * aspect))}[axis]


@dataclass
class Camera:
    """A Mitsuba perspective or thin-lens sensor: `to_world` maps camera space (+z forward, +x left, +y up) to
    the world. `width` x `height` is the image rendered: the film's crop window at (`crop_x`, `crop_y`) of a film
    of `film_width` x `film_height` (None: the whole film). `principal_x`, `principal_y` shift the principal
    point by a fraction of the film size; `aperture_radius` > 0 makes a thin lens focused at `focus_distance`;
    `rfilter` is the reconstruction filter: "box", "tent" with `filter_radius`, "gaussian" with `filter_stddev`,
    "mitchell" with `filter_b` and `filter_c`, "catmullrom", or "lanczos" with `filter_radius` lobes. `fov_x` is
    the horizontal field of view; the one the scene declared spans `fov_axis`, which a film of another size keeps
    (`resized`)."""

    to_world: np.ndarray
    fov_x: float
    width: int
    height: int
    near_clip: float = 1e-2
    far_clip: float = 1e4
    film_width: int | None = None
    film_height: int | None = None
    crop_x: int = 0
    crop_y: int = 0
    principal_x: float = 0.0
    principal_y: float = 0.0
    aperture_radius: float = 0.0
    focus_distance: float = 0.0
    rfilter: str = "box"
    filter_radius: float = 1.0
    filter_stddev: float = 0.5
    filter_b: float = 1.0 / 3.0
    filter_c: float = 1.0 / 3.0
    fov_axis: str = "x"  # the film's extent the declared field of view spans (`FOV_AXES`): kept by another size

    @property
    def filter_extent(self):
        """The reconstruction filter's radius in pixels (Mitsuba's: 0.5 for the box, 4 stddev for a Gaussian, 2
        for the cubics, the lobes for Lanczos)."""
        return {"box": 0.5, "tent": self.filter_radius, "lanczos": self.filter_radius, "mitchell": 2.0,
                "catmullrom": 2.0}.get(self.rfilter, 4.0 * self.filter_stddev)

    @property
    def film_size(self):
        """(width, height) of the whole film."""
        return (self.film_width or self.width, self.film_height or self.height)

    def resized(self, width, height):
        """The camera with a whole film of width x height, uncropped, its declared field of view spanning the same
        `fov_axis` (a view declared 40 degrees tall stays 40 degrees tall), as the scene declared at that size. A
        size that is not one keeps the angle: `camera_problem` refuses it."""
        fw, fh = self.film_size
        fov_x = self.fov_x
        if is_number(width, True) and is_number(height, True) and width > 0 and height > 0:
            t = math.tan(math.radians(fov_x) / 2.0) / tan_x_per_axis(self.fov_axis, fw / fh)
            fov_x = math.degrees(2.0 * math.atan(t * tan_x_per_axis(self.fov_axis, width / height)))
        return dataclasses.replace(self, width=width, height=height, film_width=None, film_height=None, crop_x=0,
                                   crop_y=0, fov_x=fov_x)


_WHOLE_FIELDS = ("width", "height", "film_width", "film_height", "crop_x", "crop_y")  # pixels: whole numbers


def camera_problem(c):
    """What makes the `Camera` `c` unusable, or None: a size, field of view, clip range, crop window or lens that
    no render can use, or a principal point or aperture so far beyond the film that its rays miss the view (Mitsuba
    renders those black)."""
    for f in dataclasses.fields(c):  # a Camera changed through the API: numbers where numbers are read
        value, whole = getattr(c, f.name), f.name in _WHOLE_FIELDS
        if f.name in ("to_world", "rfilter", "fov_axis") or (value is None and f.name in ("film_width",
                                                                                             "film_height")):
            continue
        if not is_number(value, whole):
            return f"camera.{f.name} must be a {'whole number' if whole else 'number'}, got {value!r}"
        try:  # a Python int of any size is a number; as a float it must be finite
            finite = math.isfinite(float(value))
        except OverflowError:
            finite = False
        if not finite:
            return f"camera.{f.name} must be finite, got {value!r}"
    if c.rfilter not in FILTERS or not (
            MIN_FILTER_REACH <= c.filter_radius <= MAX_FILTER_RADIUS
            and MIN_FILTER_REACH <= 4 * c.filter_stddev <= MAX_FILTER_RADIUS):
        return (f"camera.rfilter must be one of {', '.join(FILTERS)}, with a filter_radius and 4 filter_stddev from "
                f"{MIN_FILTER_REACH:g} to {MAX_FILTER_RADIUS:g} pixels")
    if c.rfilter == "lanczos" and c.filter_radius != int(c.filter_radius):
        return f"a lanczos filter's lobes (camera.filter_radius) must be a whole number, got {c.filter_radius!r}"
    if not (abs(c.filter_b) <= MAX_CUBIC_PARAMETER and abs(c.filter_c) <= MAX_CUBIC_PARAMETER):
        return (f"camera.filter_b and filter_c (a mitchell filter's B and C) must be within "
                f"±{MAX_CUBIC_PARAMETER:g}, got {c.filter_b!r} and {c.filter_c!r}")
    m = c.to_world
    if not isinstance(m, np.ndarray) or m.shape != (4, 4) or m.dtype.kind not in "fiu" \
            or not np.all(np.isfinite(m)) or not np.all(m[3] == (0, 0, 0, 1)) \
            or not abs(np.linalg.det(m[:3, :3] / max(np.abs(m[:3, :3]).max(), 1e-300))) >= 1e-12:
        return "the camera's to_world must be a finite, invertible affine 4x4 array (last row 0 0 0 1)"
    off = float(np.abs(m[:3, :3] @ m[:3, :3].T - np.eye(3)).max())
    if off > MAX_CAMERA_SCALE:
        return (f"the camera's to_world scales or shears (M M^T differs from the identity by {off:.3g}): a camera "
                "takes only a rotation and a translation, as Mitsuba requires (scale the scene, or change the fov)")
    if c.fov_axis not in FOV_AXES:
        return f"camera.fov_axis must be one of {', '.join(FOV_AXES)}, got {c.fov_axis!r}"
    for what, val in (("film_width", c.film_width), ("film_height", c.film_height)):
        if val is not None and not 1 <= val <= MAX_FILM_EXTENT:
            return f"{what} must be a whole number from 1 to {MAX_FILM_EXTENT}, got {val}"
    for what, val in (("width", c.width), ("height", c.height)):
        if int(val) != val or not 1 <= val <= MAX_FILM_SIDE:
            return f"{what} must be a whole number from 1 to {MAX_FILM_SIDE}, got {val}"
    if not 0.0 < c.fov_x <= MAX_FOV + FOV_ROUNDING:
        return (f"field of view must be above 0 and at most {MAX_FOV:g} degrees across, got {c.fov_x:.10g} (wider, a "
                "perspective image shrinks the whole scene to a few pixels at its centre)")
    fw, fh = c.film_size
    fov_y = math.degrees(2.0 * math.atan(math.tan(math.radians(c.fov_x) / 2.0) * fh / fw))
    if fov_y > MAX_FOV + FOV_ROUNDING:
        return (f"a field of view {c.fov_x:.10g} degrees across a {fw}x{fh} film is {fov_y:.10g} degrees tall, more "
                f"than {MAX_FOV:g} (taller, a perspective image shrinks the whole scene to a few pixels at its "
                "centre)")
    if not 0.0 < c.near_clip < c.far_clip:
        return "near_clip must be positive and smaller than far_clip"
    if not (0 <= c.crop_x and c.crop_x + c.width <= fw and 0 <= c.crop_y and c.crop_y + c.height <= fh):
        return f"the crop window {c.width}x{c.height} at ({c.crop_x}, {c.crop_y}) does not fit the {fw}x{fh} film"
    if not (c.aperture_radius >= 0 and (c.aperture_radius == 0 or c.focus_distance > 0)):
        return "a thin lens needs aperture_radius >= 0 and a positive focus_distance"
    if not (abs(c.principal_x) <= MAX_PRINCIPAL_OFFSET and abs(c.principal_y) <= MAX_PRINCIPAL_OFFSET):
        return (f"principal_point_offset ({c.principal_x:g}, {c.principal_y:g}) moves the image more than "
                f"{MAX_PRINCIPAL_OFFSET:g} film sizes off its axis, where its rays run along the film plane "
                "(an offset is a fraction of the film: 0.1 moves it by a tenth)")
    if c.aperture_radius > MAX_APERTURE_RATIO * c.focus_distance:
        return (f"aperture_radius {c.aperture_radius:g} is more than {MAX_APERTURE_RATIO:g} times the focus_distance "
                f"{c.focus_distance:g}: the lens's rays would run along its plane and its image be blur")
    return None
