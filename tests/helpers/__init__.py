"""Helpers the test folders share: ``numerics`` (tolerances derived from the problem) and ``sweep_tasks`` (task
functions the sweep runner's worker processes import by name). ``tests/`` is on every pytest process's path
(its rootdir ``conftest.py``), so tests import them as ``helpers.numerics`` and ``helpers.sweep_tasks``."""
