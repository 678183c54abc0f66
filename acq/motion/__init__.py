"""The vehicle's motion: trajectories from odometry, GNSS, their fusion and INS files."""
