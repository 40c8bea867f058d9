"""The ``mrcomm`` commands, one module each with its parser (``add_parser(command)``) and its run (``run(args)``;
``train`` also holds ``convert-run``). The work they start lives in the modules below them (``experiments/train.py``,
``race.py``, ``comparison.py``, ``learning_report.py``, …); ``experiments/cli.py`` puts the parsers together.
"""
