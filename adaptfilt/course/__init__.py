"""The course: what the notebooks use so that a chapter reads as prose, and the book built from them.
It may import the library and the pipeline (``adaptfilt.experiments``); nothing else imports it
(``docs/ARCHITECTURE.md``).

* :mod:`~adaptfilt.course.common` -- every chapter: :func:`~adaptfilt.course.common.show_source`, scores with
  bootstrap bands;
* :mod:`~adaptfilt.course.bayes`, :mod:`~adaptfilt.course.moments`, :mod:`~adaptfilt.course.myopia`,
  :mod:`~adaptfilt.course.adaptation` -- chapters 1, 2, 3 and 4;
* :mod:`~adaptfilt.course.reporting` -- chapter 5: the bootstrap, paired differences, intervals over seeds;
* :mod:`~adaptfilt.course.policy_gradient` -- chapter 6: the policy gradient derived on toys with known answers;
* :mod:`~adaptfilt.course.training` -- chapters 6 and 7: training the actor-critic;
* :mod:`~adaptfilt.course.policy_reading` -- chapter 8 (and chapter 7's widget): what policies choose;
* :mod:`~adaptfilt.course.paper_common` -- chapters 9-11: what they share of a stored evaluation (seed tables,
  grid usage, Figures 3 and 6); :mod:`~adaptfilt.course.ungm_ukf`, :mod:`~adaptfilt.course.ctm_ukf`,
  :mod:`~adaptfilt.course.ctm_sif` -- each chapter's own analyses (9, 10, 11);
* :mod:`~adaptfilt.course.seed_results` -- chapters 12-13 (and 5, 8, 14, 15): results over training seeds;
* :mod:`~adaptfilt.course.beyond_studies` -- chapters 14-17: the studies beyond the paper;
* :mod:`~adaptfilt.course.particle_count` -- chapter 17: posteriors, run errors and KLD-sampling's count;
* :mod:`~adaptfilt.course.coursemap` -- which chapter builds which library module;
* :mod:`~adaptfilt.course.prose_numbers` -- the check that a chapter's prose quotes only numbers it printed;
* :mod:`~adaptfilt.course.quoted_times` -- the check that the times the README, REPRODUCTION.md and
  docs/RUNNING.md quote are the recorded ones;
* :mod:`~adaptfilt.course.book` -- ``adaptfilt book``: the static book (mdBook).
"""
