"""Renderer pieces around the `.rdsl` kernels: camera and film setup, images, progress.

The per-sample math lives in ``stdlib/render/*.rdsl``; this package computes the uniforms
those kernels take and handles files and terminal output.
"""

from .camera import camera_uniforms
from .film import FILTERS, develop, film_uniforms, new_accumulator
from .image import read_exr, read_exr_channels, rmse, write_exr, write_image, write_png
from .progress import Progress, summary_line

__all__ = ["FILTERS", "Progress", "camera_uniforms", "develop", "film_uniforms",
           "new_accumulator", "read_exr", "read_exr_channels", "rmse", "summary_line",
           "write_exr", "write_image", "write_png"]
