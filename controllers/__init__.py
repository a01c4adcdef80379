"""Motion planning of the clamp stroke: optimal control through the plant model, baselines."""
