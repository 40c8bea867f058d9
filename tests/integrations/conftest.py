"""The framework tests run where their framework is installed: ``make test-torchrl``, ``make test-benchmarl``,
``make test-rllib`` each build a venv with one framework and run its file here; ``make test-ray`` does the same for
the sweep runner on a local Ray cluster.

The base install (``make test``) has none of them, so there these files are not collected at all (rather than
collected and skipped): a skipped test would claim a coverage the base run does not have.
"""

from importlib.util import find_spec
from pathlib import Path

FRAMEWORK_OF = {
    "test_torchrl.py": "torchrl",
    "test_benchmarl.py": "benchmarl",
    "test_rllib.py": "ray",
    "test_ray.py": "ray",
}

collect_ignore = [name for name, module in FRAMEWORK_OF.items() if find_spec(module) is None]

# test_wheel.py checks an installed wheel (`make test-wheel`); in a venv where mrcomm_env comes from this source tree
# (the editable install of `make test`, or the framework venvs) there is no wheel to check
_REPO = Path(__file__).resolve().parents[2]
if not find_spec("mrcomm_env") or Path(find_spec("mrcomm_env").origin).resolve().is_relative_to(_REPO):
    collect_ignore.append("test_wheel.py")
