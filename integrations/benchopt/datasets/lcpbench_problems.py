"""lcpbench's problem families and shipped stored sets as benchopt datasets.

``problem`` is an lcpbench problem spec as ``lcpbench run --problem`` takes it (a family such
as ``planted`` or ``fathi``, a shipped set such as ``set-paper-lattice-m3``, or
``stored:path=my-set.h5``; ``lcpbench list`` names them all) and ``instance`` the index of one
of its instances. Select one on the command line with
``-d "lcpbench[problem=set-paper-lattice-m3,instance=3]"``.
"""

from benchopt import BaseDataset

from lcpbench.run.runner import generate
from lcpbench.run.sweep import expand


class Dataset(BaseDataset):
    name = "lcpbench"
    requirements: list = []
    parameters = {
        "problem": ["set-paper-lattice-m3", "set-lattice-bim-m3", "planted", "bifidelity"],
        "instance": [0],
    }
    test_parameters = {"problem": ["fathi"], "instance": [0]}

    def get_data(self):
        specs = expand(self.problem, "problem")
        if len(specs) != 1:
            raise ValueError(f"problem {self.problem!r} names {len(specs)} parameter "
                             "combinations; give one value per parameter")
        lcps = generate(specs[0])
        if not 0 <= self.instance < len(lcps):
            raise ValueError(f"instance {self.instance} is out of range: {self.problem!r} has "
                             f"{len(lcps)} instance(s), 0..{len(lcps) - 1}")
        return dict(lcp=lcps[self.instance], problem=self.problem)
