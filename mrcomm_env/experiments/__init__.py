"""The experiments layer, on top of the envs and the policies: evaluation, reproductions, the benchmark, the
generated docs and the ``mrcomm`` command. Nothing below this package imports it. Every result file it writes
goes through :mod:`mrcomm_env.experiments.io` (written to a temporary file, then renamed into place)."""
