"""The shipped rig configurations (YAML), read with importlib.resources: sim.yaml, the
simulated rig, is the default of ``acq record``."""
