"""The numpy toy-reach tasks (tests, smoke runs, examples): see :mod:`d5rl.envs.toy.task`."""
