"""Training the library's learned policies (the `train` extra), split as CleanRL splits a run: the
rewards (rewards.py), the env a recipe trains in (env.py), the algorithms (algorithms.py) and the
loop that runs a recipe into a library (loop.py)."""
