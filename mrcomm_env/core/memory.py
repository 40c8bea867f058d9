"""The memory budget every environment checks at construction.

Each argument of an environment has its own documented range, but arguments that are each in range can
together need more memory than a machine has (RendezvousMapping with a day-long window *and* a high
observation rate; a large team *and* a large map). So every environment class states how much memory one
instance needs at its peak, as a short formula of its arguments (:meth:`MrcommParallelEnv.memory_estimate`,
shown on its ``docs/envs`` page), and construction refuses arguments whose estimate is over the budget with
a ``ValueError`` naming the arguments, the estimate and the budget. The budget is the argument
``memory_budget_gib`` that every environment takes: :data:`DEFAULT_MEMORY_BUDGET_GIB` unless a user raises it
on purpose. ``tests/core/test_memory.py`` holds each formula to the measured peak within a factor of 2.

The estimate counts what the environment itself allocates (its arrays and per-step temporaries), not the
Python interpreter and the libraries it imports.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from mrcomm_env.core.config import Param, Real

#: the default budget: one env next to a test run or a training process on a 24 GiB, 2-core machine
DEFAULT_MEMORY_BUDGET_GIB = 4.0
#: the name of the argument every environment takes
BUDGET_ARGUMENT = "memory_budget_gib"
GIB = float(2**30)

MEMORY_BUDGET_PARAM = Param(
    DEFAULT_MEMORY_BUDGET_GIB,
    "most memory (GiB) this env may need by its own estimate (see *Memory* below); arguments whose estimate is "
    "over it are refused at construction. Raise it on purpose for a larger run",
    Real(0.0, 1e6, lo_open=True, fuzz=(1.0, 8.0)),
)


def check_memory_budget(owner: str, estimate_bytes: float, cfg: Mapping[str, Any], arguments: tuple[str, ...]) -> None:
    """Raise ``ValueError`` when ``estimate_bytes`` is over ``cfg['memory_budget_gib']``, naming ``arguments``."""
    budget = float(cfg[BUDGET_ARGUMENT])
    if estimate_bytes <= budget * GIB:
        return
    named = ", ".join(f"'{arg}'={cfg[arg]!r}" for arg in arguments) or "the arguments"
    raise ValueError(
        f"{owner}: arguments {named} need an estimated {estimate_bytes / GIB:.3g} GiB, over the memory budget of "
        f"{budget:g} GiB; make them smaller, or raise the budget on purpose with '{BUDGET_ARGUMENT}'"
    )
