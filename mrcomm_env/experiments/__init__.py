"""The experiments layer, on top of the envs and the policies: evaluation, reproductions, the benchmark, the
generated docs and the ``mrcomm`` command. Nothing below this package imports it."""
