"""MapSync-v0 (paper 002): bandwidth-limited occupancy-map synchronisation between robots."""
