"""Files in and out: images (EXR, PFM, PNG) and render statistics (JSON)."""
from .atomic import staged_writes
from .case_images import case_colours, write_case_images
from .image import check_writable, read_exr, read_pfm, tonemap_srgb, write_exr, write_image, write_pfm, write_png
from .stats import summary, write_stats

__all__ = ["case_colours", "check_writable", "read_exr", "read_pfm", "staged_writes", "summary", "tonemap_srgb",
           "write_case_images", "write_exr", "write_image", "write_pfm", "write_png", "write_stats"]
