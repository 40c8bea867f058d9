"""RendezvousMapping-v0: decentralised multi-vehicle mapping with limited connectivity (Chapman & Sukkarieh)."""
