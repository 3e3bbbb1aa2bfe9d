"""What is in the world: camera models, markers, lights, poses. Plain data; no renderer imports."""
