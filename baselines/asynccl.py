"""Scripted baselines of AsyncCL-v0: the paper's information-transfer schemes (§III), used every step.

* ``scheme1`` — every robot sends only its own row (its own packets the neighbour lacks), §III-A.
* ``scheme2_q1``, ``scheme2_q2``, ``scheme2_q4``, ``scheme2_q8`` — every robot sends everything it
  holds from its q oldest non-discarded time steps, §III-B.
* ``scheme2_qinf`` — every robot sends everything the neighbour lacks, after exchanging the lists
  L_i (the D1/D2 book-keeping of §III-B.1; the scheme of Leung et al. [11]).
* ``silent`` — nobody sends (lower bound on bits, upper bound on delay).
* ``random`` — a uniformly random mode per robot and step.
"""

from __future__ import annotations

from mrcomm_baselines.common import RandomPolicy
from mrcomm_env.core.policy import Policy

ENV_ID = "mrcomm/AsyncCL-v0"
DEFAULT_POLICY = "scheme2_qinf"


class FixedMode(Policy):
    """Every robot uses the same transfer mode at every step."""

    mode = "silent"

    def reset(self, views, seed=None) -> None:
        super().reset(views, seed)
        names = tuple(views.params["modes"])
        if self.mode not in names:
            raise ValueError(f"policy '{self.name}' needs mode {self.mode!r} in the env's argument 'modes' {names}")
        self._action = int(names.index(self.mode))

    def act(self, observations, views):
        return dict.fromkeys(observations, self._action)


def _fixed(mode: str, from_paper: str = ""):
    attributes = {"mode": mode, "name": mode, "__doc__": f"Always `{mode}`.", "FROM_PAPER": from_paper}
    return type(f"Policy_{mode}", (FixedMode,), attributes)


POLICIES = {
    "scheme1": _fixed("scheme1", "Scheme 1, §III-A"),
    "scheme2_q1": _fixed("scheme2_q1", "Scheme 2, §III-B"),
    "scheme2_q2": _fixed("scheme2_q2", "Scheme 2, §III-B"),
    "scheme2_q4": _fixed("scheme2_q4", "Scheme 2, §III-B"),
    "scheme2_q8": _fixed("scheme2_q8", "Scheme 2, §III-B"),
    "scheme2_qinf": _fixed("scheme2_qinf", "Scheme 2 with q = ∞, §III-B, the scheme of [11]"),
    "silent": _fixed("silent"),
    "random": RandomPolicy,
}
