"""Studies, benchmarks and data generators built on the library (``pneumatic_env.studies``).

They live beside the package (``studies/``) and install inside its namespace; the library
never imports them. ``pneumatic-env paper``, ``speed`` and ``rig`` run them.

* ``paper``: the paper's experiments (figures and table); ``convergence``: substep
  convergence against ``reference_solution`` (an independent SciPy model); ``tube_study``.
* ``speed``: speed against Pendulum-v1, SyncVectorEnv and SciPy (docs/speed.md).
* ``virtual_rig`` (with ``segmented_line``): synthetic recordings with effects written
  independently of the candidates; ``identification_eval``: the confusion-matrix evaluation.
"""
