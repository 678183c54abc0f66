"""acq: mobile-mapping acquisition, synchronisation, calibration and colouring."""

__version__ = "0.1.0"
