"""Bundled models, each a package of parts on the generic core.

* :mod:`hhra_phys.models.hhra`: the valve-controlled helical hydraulic rotary
  actuator of the reference paper (:class:`~hhra_phys.models.hhra.HHRAModel`), its
  physical view and its simulated rig;
* :mod:`hhra_phys.models.cylinder`: the valve-controlled double-acting linear
  cylinder.
"""

__all__: list[str] = []
