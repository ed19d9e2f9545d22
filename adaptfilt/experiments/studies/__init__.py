r"""The studies of ``adaptfilt beyond``, one file each, named by its ``--studies`` word; each implements
:class:`adaptfilt.experiments.study.Study`. A new study is a new file here and one entry in :data:`ALL`.
"""
from __future__ import annotations

from adaptfilt.experiments.studies import anchor, cand, gain, look, mlanchor, ood, particles, raw, sif

#: Every study, in the order the driver runs their phases and writes their summaries and tables: the
#: learned-group studies (mlanchor after anchor, whose recipe it takes), then those that show what the others
#: trained (look), then the retuning (ood), then the learned gain beside the learned kappa (gain).
ALL = (cand, sif, raw, anchor, mlanchor, particles, look, ood, gain)
#: By name.
BY_NAME = {s.NAME: s for s in ALL}

__all__ = ["ALL", "BY_NAME", "anchor", "cand", "gain", "look", "mlanchor", "ood", "particles", "raw", "sif"]
