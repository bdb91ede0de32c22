"""Experiments on simulated scenes: `data` prepares reviewed scenes, `paper` reproduces the
paper's Tables 7 and 8 (`tracklabel experiment paper`)."""
