"""MultiHop-v0: location-based multi-hopping of state estimates over TDMA (Julian et al., paper 003)."""

from mrcomm_env.multihop.env import MultiHopEnv

__all__ = ["MultiHopEnv"]
