"""bench-ctl: AVR model validation bench controller."""

__version__ = "0.1.0"
