"""Suite-wide settings: one BLAS thread, headless plots, a memory cap per test process, Hypothesis profiles.

**The memory cap.** Each pytest process (the controller and every xdist worker) lowers its own address-space
limit (``RLIMIT_AS``) to ``MRCOMM_TEST_MEMORY_GIB`` (default :data:`DEFAULT_CAP_GIB`), never above a limit it
inherited (``prlimit --as``). A runaway allocation then raises ``MemoryError`` in the test that made it, which
fails and names itself, instead of growing until the kernel kills the worker (which once left ``make test``
hung for good). Child processes a test starts inherit the cap. Two workers at the cap fit the 24 GiB machine.

**Hypothesis.** Profile ``ci`` (the default, used by ``make test`` and CI) is derandomized: the same examples on
every machine and every run, so a fresh machine cannot draw what ours never did. Profile ``fuzz`` (``make fuzz``,
``HYPOTHESIS_PROFILE=fuzz``) draws 1,000 fresh examples per property with a seed that pytest prints, for wide
exploration off CI.
"""

import os
import resource

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import matplotlib  # noqa: E402

matplotlib.use("Agg")

#: address space per test process: the interpreter with torch and numba maps about 1 GiB; the largest documented
#: env (tests/core/test_limits.py) peaks under 2 GiB resident
DEFAULT_CAP_GIB = 6.0
CAP_VARIABLE = "MRCOMM_TEST_MEMORY_GIB"


def cap_address_space(gib: float) -> int:
    """Lower this process's soft and hard ``RLIMIT_AS`` to ``gib`` GiB (or keep a lower inherited one); returns it."""
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = int(gib * 2**30)
    for inherited in (soft, hard):
        if inherited != resource.RLIM_INFINITY:
            cap = min(cap, inherited)
    resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
    return cap


# 0 turns the cap off: the Ray targets (make test-rllib, test-ray) start raylets that map an object store sized
# from the machine's memory, beyond any per-process address-space cap
if float(os.environ.get(CAP_VARIABLE, DEFAULT_CAP_GIB)) > 0:
    cap_address_space(float(os.environ.get(CAP_VARIABLE, DEFAULT_CAP_GIB)))


def register_hypothesis_profiles() -> None:
    """The ``ci`` and ``fuzz`` profiles (module docstring); the framework venvs (``make test-torchrl``, …) have no
    Hypothesis and run no property test."""
    try:
        from hypothesis import HealthCheck, settings
    except ImportError:
        return
    common = {"deadline": None, "suppress_health_check": [HealthCheck.too_slow, HealthCheck.filter_too_much]}
    settings.register_profile("ci", derandomize=True, print_blob=True, **common)
    settings.register_profile("fuzz", max_examples=1000, print_blob=True, **common)
    settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


register_hypothesis_profiles()


@pytest.fixture(autouse=True, scope="session")
def sb3_logs_in_the_suites_temporary_folder(tmp_path_factory):
    """SB3 makes an empty ``<tmp>/SB3-<time>`` folder on every ``learn()`` of a model without a logger of its own
    (``stable_baselines3.common.logger.configure``); the tests that train such models put it in pytest's
    temporary folder instead of leaving hundreds in /tmp."""
    previous = os.environ.get("SB3_LOGDIR")
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3-logs"))
    yield
    if previous is None:
        os.environ.pop("SB3_LOGDIR", None)
    else:
        os.environ["SB3_LOGDIR"] = previous


#: what the package ships beside its code, which no test may write (a test once patched a name the exporter no
#: longer read and shipped its tiny model as MapSync's)
SHIPPED_DATA = [
    os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "agents", folder)
    for folder in ("pretrained", "configs")
]


def shipped_files() -> dict[str, tuple[int, int]]:
    """(modification time, size) of every file under :data:`SHIPPED_DATA`."""
    found = {}
    for root in SHIPPED_DATA:
        for folder, _, names in os.walk(root):
            for name in names:
                path = os.path.join(folder, name)
                status = os.stat(path)
                found[path] = (status.st_mtime_ns, status.st_size)
    return found


@pytest.fixture(autouse=True)
def no_test_writes_the_shipped_models():
    before = shipped_files()
    yield
    after = shipped_files()
    changed = sorted(path for path in before.keys() | after.keys() if before.get(path) != after.get(path))
    assert not changed, f"this test wrote into the package's shipped data: {changed}"
