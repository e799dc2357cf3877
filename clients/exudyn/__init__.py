"""The Exudyn adapter: the mechanism (bodies, joints), PTOs, moorings, MoorDyn."""
