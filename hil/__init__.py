"""hil: the shells of the thruster HIL emulator (CLI, process supervision, recording, reports)."""
