"""What the simulator misses against a measured trace (docs/discrepancy.md).

``measure`` prepares the measurement and ``where`` says where a model disagrees; ``fit``
calibrates a configuration by simulation error; ``moves`` are the changes a model can make,
``correction`` the generic correction they must beat, ``score`` a model's cross-validated score
and the acceptance test, ``engine`` the selection; ``report`` writes the report files;
``cases`` makes synthetic measured traces with hidden effects for tests and the study.
"""
