"""thruster_fdd_shore: what stays ashore. The thruster simulator and its presets, the
microcontroller emulator and the firmware co-simulation, training, export and evaluation of the
models, the reference load curves, offline diagnosis, replay checks, the discrepancy workflow,
and the ``thruster-fdd`` command. It depends on the vehicle package ``thruster_fdd``, never the
other way round."""
