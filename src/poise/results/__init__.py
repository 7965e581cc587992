"""Results: in-memory run results and the HDF5 writer/reader."""
