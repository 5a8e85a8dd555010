"""Applications: the ``giwbc`` command line and what its commands run (demo, deploy, evaluation,
sim-to-sim, training, play). Each module owns its command's argparse; the library beneath carries none."""
