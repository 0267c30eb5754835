"""Stored LCP sets: the HDF5 file format, its writer and its verified reader.

A set is one file; see :mod:`lcpbench.sets.common` for the layout, the integrity rules and
the cost convention. Problem plugins read sets with :func:`read_set`; ``lcpbench generate``
writes them with :class:`SetWriter`.
"""

from lcpbench.sets.common import (
                                  COST_CONVENTION,
                                  FORMAT,
                                  READ_BUDGET,
                                  VERSION,
                                  StoredSetError,
                                  human_bytes,
                                  parse_instances,
                                  read_budget,
                                  set_problem_name,
)
from lcpbench.sets.read import instance_ids, read_instance, read_set, set_info
from lcpbench.sets.write import SetWriter, seal_set

__all__ = ["SetWriter", "seal_set", "StoredSetError", "read_set", "read_instance", "set_info",
           "instance_ids", "parse_instances", "set_problem_name", "FORMAT", "VERSION",
           "COST_CONVENTION", "READ_BUDGET", "read_budget", "human_bytes"]
