"""Pixel operations shared by every camera path: Bayer binning and tone curves."""
