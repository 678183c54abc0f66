"""Time: device clocks mapped to the host clock, scan and frame stamps, pairing, offline
re-timing, UTC."""
