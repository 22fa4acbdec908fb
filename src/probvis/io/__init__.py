"""Files in and out: images (EXR, PFM, PNG) and render statistics (JSON)."""
from .image import check_writable, read_exr, read_pfm, tonemap_srgb, write_exr, write_image, write_pfm, write_png
from .stats import summary, write_stats

__all__ = ["check_writable", "read_exr", "read_pfm", "summary", "tonemap_srgb", "write_exr", "write_image",
           "write_pfm", "write_png", "write_stats"]
