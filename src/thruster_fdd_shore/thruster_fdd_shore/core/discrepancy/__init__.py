"""What the simulator misses against a measured trace (docs/discrepancy.md).

``measure`` prepares the measurement and says where a model disagrees; ``fit`` calibrates a
configuration by simulation error; ``search`` adds effects of the vocabulary and names the
missing ones; ``report`` writes the report files; ``cases`` makes synthetic measured traces with
hidden effects for tests and the study.
"""
