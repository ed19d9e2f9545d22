"""The course: what the notebooks use so that a chapter reads as prose, and the book built from them.
It may import the library and the pipeline (``adaptfilt.experiments``); nothing else imports it
(``docs/ARCHITECTURE.md``).

* :mod:`~adaptfilt.course.helpers` -- chapters 1-4: Bayes on a grid, moments, myopia;
* :mod:`~adaptfilt.course.learning` -- chapters 5 and 9-11: the actor-critic, results over seeds;
* :mod:`~adaptfilt.course.paper_results` -- chapters 6-8: the paper's experiments from ``data/``;
* :mod:`~adaptfilt.course.earlier_numbers` -- earlier numbers that chapters 7 and 8 compare with;
* :mod:`~adaptfilt.course.coursemap` -- which chapter builds which library module;
* :mod:`~adaptfilt.course.book` -- ``adaptfilt book``: the static book (mdBook).
"""
