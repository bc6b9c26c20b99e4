"""Motion sources and the feature-matrix contract they all produce (synthetic generator, later frame sets and BVH)."""
