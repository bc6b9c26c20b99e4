"""Frame sets: rendered cartoon clips, keyframe annotations, CVAT import and key points from curves."""
