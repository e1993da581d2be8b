"""WidowX 250 multi-stage bin sorting: model (scene), controller (IK), task (env), scripted policy, data."""
