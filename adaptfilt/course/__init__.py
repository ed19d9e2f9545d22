"""The course: what the notebooks use so that a chapter reads as prose, and the book built from them.
It may import the library and the pipeline (``adaptfilt.experiments``); nothing else imports it
(``docs/ARCHITECTURE.md``).

* :mod:`~adaptfilt.course.common` -- every chapter: :func:`~adaptfilt.course.common.show_source`, scores with
  bootstrap bands;
* :mod:`~adaptfilt.course.bayes`, :mod:`~adaptfilt.course.moments`, :mod:`~adaptfilt.course.myopia`,
  :mod:`~adaptfilt.course.adaptation` -- chapters 1, 2, 3 and 4;
* :mod:`~adaptfilt.course.reporting` -- chapter 5: the bootstrap, paired differences, intervals over seeds;
* :mod:`~adaptfilt.course.learning` -- chapters 6-7 and 11-13: the actor-critic, results over seeds;
* :mod:`~adaptfilt.course.paper_results` -- chapters 8-10: the paper's experiments from ``data/``;
* :mod:`~adaptfilt.course.coursemap` -- which chapter builds which library module;
* :mod:`~adaptfilt.course.prose_numbers` -- the check that a chapter's prose quotes only numbers it printed;
* :mod:`~adaptfilt.course.book` -- ``adaptfilt book``: the static book (mdBook).
"""
