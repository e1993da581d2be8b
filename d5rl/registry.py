"""Task ids, task specs and the global task list.

One id grammar, parsed here and nowhere else::

    <family>-<name>-v<version>      e.g. a1-walk-v0, kitchen-standard-mixed-v0, wx-sorting-v0
    <family>-<name>-<variant>-v<version>   the same task on another dataset (a dataset variant),
                                    e.g. kitchen-standard-mixed-human-v0 (see :func:`variant_id`)

Each env family registers its own tasks next to its code, in
``d5rl/envs/<family>/registration.py``, by calling :func:`register`.  The global
list is assembled by importing every family package's ``registration`` module,
so adding a family never touches a central table.
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib
import importlib.util
import pkgutil
import re
from collections.abc import Callable
from typing import Any

from d5rl.errors import D5RLError, TaskIdError, UnknownTaskError

TASK_ID_RE = re.compile(r"^(?P<family>[a-z0-9]+)-(?P<name>[a-z0-9]+(?:-[a-z0-9]+)*)-v(?P<version>\d+)$")


@dataclasses.dataclass(frozen=True)
class TaskId:
    family: str
    name: str
    version: int

    def __str__(self) -> str:
        return f"{self.family}-{self.name}-v{self.version}"


def parse_task_id(task_id: str) -> TaskId:
    """Split ``a1-walk-v0`` into ``TaskId('a1', 'walk', 0)``; raise :class:`TaskIdError` if malformed."""
    m = TASK_ID_RE.match(task_id) if isinstance(task_id, str) else None
    if m is None:
        raise TaskIdError(
            f"{task_id!r} is not a task id",
            "task ids look like 'a1-walk-v0' or 'kitchen-standard-mixed-v0'; run `d5rl list` for all of them",
        )
    return TaskId(m["family"], m["name"], int(m["version"]))


@dataclasses.dataclass(frozen=True)
class DatasetSpec:
    """How a task's offline dataset is made.

    Several tasks may share one dataset (``name``): a1-walk and a1-run use the same
    replay buffers, and the standard kitchen tasks the same demonstrations.  A task
    then supplies ``relabel`` to compute its own rewards from the stored data.
    """

    name: str  # directory name under $D5RL_HOME/datasets, e.g. "a1-locomotion"
    version: int  # bump when the generated content changes (CHANGELOG line too)
    # "module:Class", a d5rl.datasets.generation.EpisodeGenerator; None for an imported dataset
    generator: str | None
    num_episodes: int  # full size of the dataset (an imported one: as many as were imported, 0 here)
    episodes_per_shard: int = 16  # unit of work, resume and atomic write
    generator_kwargs: dict = dataclasses.field(default_factory=dict)
    default_seed: int = 0
    description: str = ""
    # "module:function" called by the loader on a finished dataset to build caches
    # derived from it (e.g. camera frames rendered from stored states); see loading.py.
    derived: str | None = None
    # Why the dataset cannot be made yet, in one line that names the command that fixes it (e.g. its
    # data agents are not trained); generating or loading it raises this before any work.
    unavailable: str | None = None
    # An imported dataset (data d5rl cannot make, e.g. human demonstrations): "module:attr" of its
    # importer, whose ``version`` identifies the conversion, ``command`` imports it and ``how`` says, in one
    # line, which commands download and import it.  Exactly one of ``generator`` and ``importer`` is set.
    importer: str | None = None

    @property
    def imported(self) -> bool:
        return self.importer is not None

    @property
    def producer(self) -> str:
        """The code that writes this dataset: its generator, or its importer."""
        return self.generator if self.generator is not None else self.importer

    # "portable": generation workers pin CPU-independent kernels (d5rl.numerics), so the bytes are the
    # same on every x86-64 machine; "native": each CPU's fastest kernels (bytes may differ across CPUs).
    # Not part of the dataset's identity: a dataset adopts "portable" at a new version unless its bytes
    # do not change.
    numerics: str = "native"
    # "module:function" (task spec, an episode's meta, env kwargs) -> the env to replay that episode's stored
    # states in, when the task's own env would not show them as they happened (a scene drawn per episode:
    # the A1 v1 floors); None: the task's env (make_env).  Used by `d5rl render --episode` and the browser.
    replay: str | None = None


@dataclasses.dataclass(frozen=True)
class ScoreRef:
    """Reference returns for normalized scores: 0 = ``random``, 1 = ``expert``."""

    random: float
    expert: float
    source: str  # how the numbers were measured (command, episodes, seed)
    expert_note: str = ""  # what the expert does on the task (e.g. its speed), shown by `d5rl info`


@dataclasses.dataclass(frozen=True)
class TaskSpec:
    id: str
    entry_point: str  # "module:Class" of the gymnasium.Env
    max_episode_steps: int
    description: str
    env_kwargs: dict = dataclasses.field(default_factory=dict)
    dataset: DatasetSpec | None = None
    # "module:function" mapping (TaskSpec, Dataset arrays) -> dict of replaced arrays
    # (e.g. rewards, terminals) when this task labels a shared dataset differently.
    relabel: str | None = None
    score: ScoreRef | None = None
    # Where an episode's normalized score comes from: "return" normalizes the episode
    # return with ``score``; "info" takes ``info["score"]`` of the episode's last step
    # (tasks whose reward is paid every step, e.g. objects currently in place).
    score_from: str = "return"
    # How the normalized score is defined, for `d5rl info` and the docs.
    score_definition: str = "(return - random) / (expert - random)"
    # The benchmark group whose settings and table rows this task shares ("kitchen-standard",
    # "kitchen-randomized", "a1", "wx"); "" = the id's family.  Read by d5rl.settings and the report.
    group: str = ""
    # What the agent observes: "state" (a flat float vector) or "pixels" (camera frames +
    # proprioception).  Picks the settings layer (pixel agents: batch 64, ...) and frame stacking.
    observation: str = "state"
    # Other datasets of the same task, by variant name: each registers as a task of its own,
    # ``variant_id(id, name)``, identical but for its dataset (e.g. {"human": <imported demos>}).
    dataset_variants: dict = dataclasses.field(default_factory=dict)
    # On a variant's spec: the variant's name and the id of the task whose data it replaces.
    variant: str = ""
    variant_of: str = ""

    @property
    def parsed(self) -> TaskId:
        return parse_task_id(self.id)

    @property
    def family(self) -> str:
        return self.parsed.family

    @property
    def benchmark_group(self) -> str:
        return self.group or self.family


def variant_id(task_id: str, variant: str) -> str:
    """The id of ``task_id`` on its dataset variant ``variant``: the variant is the name's last part,
    ``kitchen-standard-mixed-v0`` + ``human`` = ``kitchen-standard-mixed-human-v0``."""
    t = parse_task_id(task_id)
    if not re.fullmatch(r"[a-z0-9]+", variant or ""):
        raise TaskIdError(f"{variant!r} is not a dataset variant name", "use lowercase letters and digits")
    return str(TaskId(t.family, f"{t.name}-{variant}", t.version))


def base_task(task_id: str) -> str:
    """The task whose dataset a variant replaces (the task itself when it is no variant)."""
    spec = get_spec(task_id)
    return spec.variant_of or spec.id


_REGISTRY: dict[str, TaskSpec] = {}
_LOADED = False


def register(spec: TaskSpec) -> TaskSpec:
    """Add a task (called by family ``registration`` modules at import), and one task per dataset
    variant (:func:`variant_id`)."""
    parse_task_id(spec.id)
    for d in [spec.dataset, *spec.dataset_variants.values()]:
        if d is not None and (d.generator is None) == (d.importer is None):
            raise ValueError(f"{spec.id}: dataset {d.name} needs exactly one of generator and importer")
    if spec.score_from not in ("return", "info"):
        raise ValueError(f"{spec.id}: score_from must be 'return' or 'info', got {spec.score_from!r}")
    if spec.observation not in ("state", "pixels"):
        raise ValueError(f"{spec.id}: observation must be 'state' or 'pixels', got {spec.observation!r}")
    if spec.id in _REGISTRY and _REGISTRY[spec.id] != spec:
        raise ValueError(f"task {spec.id} registered twice with different specs")
    _REGISTRY[spec.id] = spec
    _register_with_gymnasium(spec)
    for name, dspec in spec.dataset_variants.items():
        register(
            dataclasses.replace(
                spec,
                id=variant_id(spec.id, name),
                dataset=dspec,
                dataset_variants={},
                variant=name,
                variant_of=spec.id,
                description=f"{spec.description}; dataset variant {name!r} ({dspec.name})",
            )
        )
    return spec


def minari_env_id(task_id: str) -> str:
    """The Gymnasium id of the environment a Minari export of ``task_id`` names (``d5rl/a1-walk-minari-v0``)."""
    tid = parse_task_id(task_id)
    return f"d5rl/{tid.family}-{tid.name}-minari-v{tid.version}"


def _register_with_gymnasium(spec: TaskSpec) -> None:
    import gymnasium

    gym_id = f"d5rl/{spec.id}"
    if gym_id in gymnasium.registry:
        return
    gymnasium.register(
        id=gym_id,
        entry_point=spec.entry_point,
        max_episode_steps=spec.max_episode_steps,
        kwargs=dict(spec.env_kwargs),
        disable_env_checker=True,
    )
    # the environment of a Minari export of this task (d5rl.datasets.export), so gymnasium.make finds its id
    gymnasium.register(
        id=minari_env_id(spec.id),
        entry_point="d5rl.datasets.export:make_minari_env",
        max_episode_steps=spec.max_episode_steps,
        kwargs={"task_id": spec.id},
        disable_env_checker=True,
    )


def register_all() -> None:
    """Import every family's ``registration`` module (on ``import d5rl``; cheap, idempotent)."""
    _load_families()


def _load_families() -> None:
    global _LOADED
    if _LOADED:
        return
    # The families are plug-ins found by name, like a task's entry point: the registry sits below d5rl.envs.
    families = importlib.util.find_spec("d5rl.envs").submodule_search_locations
    for info in sorted(pkgutil.iter_modules(families), key=lambda i: i.name):
        if info.ispkg:
            try:
                importlib.import_module(f"d5rl.envs.{info.name}.registration")
            except ModuleNotFoundError as e:
                if e.name != f"d5rl.envs.{info.name}.registration":
                    raise
    _LOADED = True


def get_spec(task_id: str) -> TaskSpec:
    """The spec of a registered task; clear error with suggestions otherwise."""
    if isinstance(task_id, TaskSpec):
        return task_id
    _load_families()
    if task_id in _REGISTRY:
        return _REGISTRY[task_id]
    if isinstance(task_id, str) and task_id.startswith("d5rl/") and task_id[5:] in _REGISTRY:
        return _REGISTRY[task_id[5:]]
    parse_task_id(task_id)  # malformed ids get the grammar error
    close = difflib.get_close_matches(task_id, list(_REGISTRY), n=3, cutoff=0.5)
    hint = f"did you mean {', '.join(close)}?" if close else "run `d5rl list` to see the registered tasks"
    raise UnknownTaskError(f"unknown task {task_id!r}", hint)


def list_tasks(family: str | None = None) -> list[str]:
    """All registered task ids (optionally of one family), sorted."""
    _load_families()
    return sorted(t for t, s in _REGISTRY.items() if family is None or s.family == family)


def resolve(ref: str) -> Any:
    """Import ``"package.module:attr"``."""
    module, _, attr = ref.partition(":")
    obj: Any = importlib.import_module(module)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


def make_env(task_id: str, **kwargs: Any):
    """Instantiate the task's environment (wrapped in a TimeLimit)."""
    import gymnasium

    spec = get_spec(task_id)
    env_cls: Callable = resolve(spec.entry_point)
    env = env_cls(**{**spec.env_kwargs, **kwargs})
    return gymnasium.wrappers.TimeLimit(env, max_episode_steps=spec.max_episode_steps)


def make_replay_env(task_id: str, meta: dict, **kwargs: Any):
    """The env that shows a stored episode of the task's dataset as it happened (``DatasetSpec.replay``)."""
    spec = get_spec(task_id)
    if spec.dataset is None or spec.dataset.replay is None:
        return make_env(spec.id, **kwargs)
    return resolve(spec.dataset.replay)(spec, meta, **kwargs)


def episode_score(task_id: str, episode_return: float, final_info: dict) -> float:
    """The normalized score of one finished episode, however the task defines it."""
    spec = get_spec(task_id)
    if spec.score_from == "info":
        if "score" not in final_info:
            raise KeyError(f"{spec.id} reports its score in info['score'], which the last step's info lacks")
        return float(final_info["score"])
    return float(normalize_score(spec, episode_return))


def normalize_score(task_id: str, raw_return):
    """Map a raw episode return to the task's normalized score (0 random, 1 expert)."""
    spec = get_spec(task_id)
    if spec.score_from == "info":
        raise D5RLError(
            f"{spec.id}'s score is not a function of the return: {spec.score_definition}",
            "use d5rl.episode_score(task_id, episode_return, final_info) with the last step's info",
        )
    if spec.score is None:
        raise D5RLError(
            f"task {task_id} has no reference scores yet",
            f"compute them with `d5rl calibrate {task_id}`",
        )
    import numpy as np

    r = spec.score
    return (np.asarray(raw_return, dtype=np.float64) - r.random) / (r.expert - r.random)
