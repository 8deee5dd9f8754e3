"""The reference paper's reproduction, kept apart from the identification core.

Nothing in the core imports this package; it imports the core (the optimisers of
:mod:`hhra_phys.optim`) to rerun the paper's experiments.

Modules:

:mod:`.benchmarks`
    The nine benchmark functions of the paper's Table 1, vectorised over populations.
:mod:`.table2`
    The optimiser study of the paper's Table 2, reproduced and extended
    (``hhra-phys benchmark``, ``experiments/table2.py``).

The paper's Table 3 (ARX against the physical model) is a run of the general method
comparison, :mod:`hhra_phys.compare`, which carries the paper's published numbers beside its
own.
"""

__all__: list[str] = []
