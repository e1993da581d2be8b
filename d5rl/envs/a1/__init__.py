"""Unitree A1 locomotion: walk (0.75 m/s), run (1.25 m/s) and hiking on a rough course."""
