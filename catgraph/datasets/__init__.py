"""Datasets: loaders for real formats and a seeded synthetic world."""

from .loaders import load_array, load_image_folder, load_traverse, load_uji
from .synthetic import SyntheticWorld, make_world

__all__ = ["SyntheticWorld", "load_array", "load_image_folder", "load_traverse", "load_uji", "make_world"]
