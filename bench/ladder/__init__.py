"""The fidelity ladder (``whiskerbench ladder``): one rendering choice varied at a time against a
high-quality reference, for the detectability study's sensitive cells and for a labeled clip,
so that the defaults can be the cheapest choices whose outcome matches the reference's."""
