"""Triangle meshes: topology, real-export repair (polygons, seams, fins), decimation."""
