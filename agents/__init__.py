"""Learning agents for the mrcomm environments; ``agents`` builds on ``mrcomm_env``, never the reverse."""

from mrcomm_agents.vecenv import AgentSlotVecEnv, make_vec_env

__all__ = ["AgentSlotVecEnv", "make_vec_env"]
