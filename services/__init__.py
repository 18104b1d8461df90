"""Team Space Fortress services. Importing the package loads nothing else: the Gymnasium id
`tsf/Role-v0` is registered by importing services/agent/envs.py, so that a live service never
pays for gymnasium's import and its env registry.

numpy's BLAS runs one thread per process unless OPENBLAS_NUM_THREADS says otherwise: bulk play
(sweeps, `tsf eval`, the vectorised env) runs one process per core, and BLAS threads that spin
for a core beside them slow a batch's network inference several times over (one eval batch:
8.7 ms with the default threads, 1.6 ms with one, on 2 busy cores). Set here, before numpy loads.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
