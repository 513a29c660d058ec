"""calib: DEM contact-parameter calibration from heap tests."""
__version__ = "0.1.0"
