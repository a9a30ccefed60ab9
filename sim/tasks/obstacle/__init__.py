"""The obstacle task: from a start to the goal past a box, on either side (a cue tile showing the side in its
variant)."""
