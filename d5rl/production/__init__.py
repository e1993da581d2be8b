"""Data production: how each family's datasets are made, a layer above the dataset format.

``d5rl.production.<family>`` holds a family's dataset generators (``DatasetSpec.generator``), the scripted
operators and data agents they replay, the relabelling of stored data for each task, the builders of
derived caches and the statistics of its data card; :mod:`d5rl.production.a1` also trains the A1 data
agents.  The simulation they run is ``d5rl.envs.<family>``, which names this code only by strings in its
registration; the dataset format they write is :mod:`d5rl.datasets`.

A generator that moved here from ``d5rl.envs.<family>`` keeps, as its ``name``, the "module:Class" its
datasets were first written under: manifests, shards and the committed references store that name, so
moving the code leaves everyone's data current.
"""
