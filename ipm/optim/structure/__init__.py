"""Structure recovery (issue #16): a beam search over trees of the universal generator's nodes, fitted to a
mesh or to masks of K >= 2 views. One job per module: the target's samples (``samples.py``), trees as
editable JSON (``program.py``), refinement, score and residual regions of one tree (``candidate.py``), the
edits, one module each (``edits/``), the settings (``settings.py``) and the search (``search.py``)."""

from ipm.optim.structure.program import count_nodes, primitive_counts, signature, structure
from ipm.optim.structure.samples import Samples, mask_samples, mesh_samples
from ipm.optim.structure.search import SearchResult, search
from ipm.optim.structure.settings import StructureSettings

__all__ = ["Samples", "SearchResult", "StructureSettings", "count_nodes", "mask_samples", "mesh_samples",
           "primitive_counts", "search", "signature", "structure"]
