"""Training glue: SB3 / sb3-contrib / SuperSuit, run directories, checkpoints."""
