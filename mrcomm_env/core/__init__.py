"""Shared mechanics of every mrcomm environment: config validation, base env, comm model, rendering."""

from mrcomm_env.core.base import MrcommParallelEnv
from mrcomm_env.core.comm import (
    BitLedger,
    TDMASchedule,
    apply_packet_loss,
    bernoulli_links,
    combined_links,
    disk_links,
    disk_pairs,
    fit_to_budget,
    grid_links,
)
from mrcomm_env.core.config import Bool, Choice, Config, Int, ListOf, Optional, Param, Real, validate_config
from mrcomm_env.core.stats import mean_ci95

__all__ = [
    "MrcommParallelEnv",
    "BitLedger",
    "TDMASchedule",
    "apply_packet_loss",
    "bernoulli_links",
    "combined_links",
    "disk_links",
    "disk_pairs",
    "fit_to_budget",
    "grid_links",
    "Bool",
    "Choice",
    "Config",
    "Int",
    "ListOf",
    "Optional",
    "Param",
    "Real",
    "validate_config",
    "mean_ci95",
]
