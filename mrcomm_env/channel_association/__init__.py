"""mrcomm/ChannelAssociation-v0 — concurrent association of wireless and visual IDs (Ivanov & Shell, paper 001)."""

from mrcomm_env.channel_association.env import ChannelAssociationEnv

__all__ = ["ChannelAssociationEnv"]
