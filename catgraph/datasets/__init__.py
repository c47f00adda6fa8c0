"""Datasets: loaders for real formats and a seeded synthetic world."""

from .loaders import load_array, load_image_folder, load_traverse, load_uji

__all__ = ["load_array", "load_image_folder", "load_traverse", "load_uji"]
