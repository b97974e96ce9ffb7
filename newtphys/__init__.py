"""NewtPhys core: the data contract shared by data_gen and probes."""

__version__ = "0.1.0"
