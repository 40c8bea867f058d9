"""The ``mrcomm`` commands, one module each with its parser (``add_parser(command)``) and its run (``run(args)``).

``mrcomm train`` and ``convert-run``, ``race`` and ``reproduce-learning`` keep theirs in the modules that do their
work (``experiments/train.py``, ``race.py``, ``learning_report.py``); ``experiments/cli.py`` puts them together.
"""
