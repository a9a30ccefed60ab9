"""The pick-and-place task: pick a bar and put it on a free mat it fits, the table deciding the place, leaving it
free, or changing during the motion."""
