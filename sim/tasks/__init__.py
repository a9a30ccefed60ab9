"""The simulator's tasks, one folder each: its scene, environment, scripted demonstrator and scoring."""
