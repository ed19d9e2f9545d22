"""The reproduction pipeline: it runs the paper's experiments and the studies beyond it, writes
``data/`` and reads it back. It imports the library (``adaptfilt.*``), never the course
(``adaptfilt.course``); nothing in the library imports it (``docs/ARCHITECTURE.md``).

* :mod:`~adaptfilt.experiments.sweep` -- independent jobs (seeds x experiments x gamma,
  evaluations) on a local process pool or a Dask cluster;
* :mod:`~adaptfilt.experiments.journal` -- one line per finished job, so that an interrupted run
  resumes;
* :mod:`~adaptfilt.experiments.jobs` -- a training or an evaluation job: the command a manifest records
  for it, its journal key, what a worker runs;
* :mod:`~adaptfilt.experiments.evaluate` -- what ``adaptfilt evaluate`` runs (files, tables, figures);
* :mod:`~adaptfilt.experiments.claims`, :mod:`~adaptfilt.experiments.references`,
  :mod:`~adaptfilt.experiments.agreement`, :mod:`~adaptfilt.experiments.fast_vs_faithful`,
  :mod:`~adaptfilt.experiments.report` -- the paper's claims, Table I, the Bayes floor and the
  reconciliation, the report;
* :mod:`~adaptfilt.experiments.reproduce` -- ``adaptfilt reproduce``: every artefact of ``data/``
  with the one command that makes it;
* :mod:`~adaptfilt.experiments.beyond` -- ``adaptfilt beyond``, the loop over the studies beyond the paper:
  one file each in :mod:`~adaptfilt.experiments.studies`, each a :class:`~adaptfilt.experiments.study.Study`;
  the science of three of them in :mod:`~adaptfilt.experiments.ood`, :mod:`~adaptfilt.experiments.look`
  and :mod:`~adaptfilt.experiments.particles_study`;
* :mod:`~adaptfilt.experiments.artefacts` -- reading ``data/`` back (for the notebooks).

The paper's experiments by name are library configuration, in :mod:`adaptfilt.experiment_registry`;
the statistics over training seeds are in :mod:`adaptfilt.seed_stats`.
"""
