"""The ground floor: the vocabulary that the flight and plant cores, the bus and the shells share.

Vehicle and scenario models (``common.vehicle``, ``common.scenario``), the models' base and error
rendering (``common.schema``), units (``common.units``), quaternion helpers
(``common.quaternion``) and the root of the exception tree (``common.errors``). It imports no
other package of this project: no YAML, no paths, no bus, no shell. ``docs/architecture.md``
says why this is a package of its own.
"""
