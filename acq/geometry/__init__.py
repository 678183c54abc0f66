"""Rotations, rigid transforms and geodesy: the lowest layer beside acq.records."""
