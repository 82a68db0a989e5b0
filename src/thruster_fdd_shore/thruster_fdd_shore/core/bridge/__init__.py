"""The bridge ashore: the microcontroller emulator on a pseudo-terminal, HoTT ESC telemetry,
the bridge firmware's build and its co-simulation on an emulated ATmega328P, the bridge check."""
