"""Recording: the configuration, the recorder daemon, device discovery and probing,
systemd notify."""
