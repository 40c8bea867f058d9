"""A MapSync robot's actions (``Discrete(5)``): idle, or open one of the sync protocols with a peer. Their own module
so that the compiled kernels (which take them as constants) and the sync sessions both import them from below."""

ACTIONS = ("idle", "equality", "bisection", "full", "sketch")
IDLE, EQUALITY, BISECTION, FULL, SKETCH = range(5)
