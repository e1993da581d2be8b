"""The executor: every parallel job of d5rl (the cells of a ``d5rl bench`` grid, the shards of a dataset and of
its render cache) runs through :class:`Executor`, in this process, in worker processes on this machine, or on a
Ray cluster.

- :class:`Executor`: submit tasks, collect how each ended (:class:`Finished`), submit a failed one again; one
  process per task (``fresh``: bench cells, for clean JAX state) or long-lived workers that pay their
  ``initializer`` once (dataset shards, whose generator is built once per worker);
- :func:`run_jobs`: a batch of jobs on an :class:`Executor`, results in order, the first failure raised.

Every worker process is a fresh interpreter set up by :mod:`d5rl.parallel.process` before it imports anything
it is sent (one compute thread: :func:`configure_worker`; ``worker_env``, read by the dynamic loader or when a
library loads, e.g. :func:`d5rl.numerics.portable_env`); on Ray, workers start with ``worker_env`` too.  Tasks
report progress with :func:`report` (any picklable payload, e.g. one finished episode); the driver receives it
through ``on_message`` whatever the backend.

Scripts without ``if __name__ == "__main__":``: a worker does not run the caller's main script, so a script
calling d5rl at top level is not run again in every worker.  Only a task that names something defined in the main
script makes its worker load it (as ``spawn`` does); a worker that re-runs such a script and reaches a d5rl lock
its parent holds stops with a one-line error naming the guard (:func:`d5rl.datasets.lock.writing`).

Stopping: on Ctrl-C or an error the driver stops its workers at once (they ignore SIGINT, so a Ctrl-C to the
whole process group is handled by the driver alone; a running task gets SIGTERM, which it sees as
``KeyboardInterrupt`` and cleans up after), and a worker whose driver dies, even by ``kill -9``, exits by itself
(``PR_SET_PDEATHSIG`` on Linux and a watchdog thread everywhere), so no orphan keeps writing.
"""

from d5rl.parallel.cluster import connect_ray, import_ray
from d5rl.parallel.executor import Executor, Ray, Workers, check_workers, run_jobs
from d5rl.parallel.process import Finished, configure_worker, die_with_parent, report

__all__ = [
    "Executor",
    "Finished",
    "Ray",
    "Workers",
    "check_workers",
    "configure_worker",
    "connect_ray",
    "die_with_parent",
    "import_ray",
    "report",
    "run_jobs",
]
