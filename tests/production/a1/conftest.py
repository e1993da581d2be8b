import pytest


@pytest.fixture
def small_trainer(tmp_path):
    """``small_trainer(agents, work_dir, **kw)``: a :class:`~d5rl.production.a1.experts.Trainer` small enough for a
    test (90 steps, the first 30 of random actions, a snapshot every 30, one update per step, seed 0), writing its
    policies under ``tmp_path / "policies"`` unless ``policy_dir`` says otherwise."""
    from d5rl.production.a1.experts import Trainer  # needs JAX: the tests that use it skip without

    def make(agents, work_dir, *, steps=90, snapshot_every=30, start_steps=30, policy_dir=None, **kw):
        return Trainer(
            list(agents),
            steps=steps,
            seed=0,
            snapshot_every=snapshot_every,
            start_steps=start_steps,
            utd=1,
            work_dir=work_dir,
            policy_dir=tmp_path / "policies" if policy_dir is None else policy_dir,
            **kw,
        )

    return make
