"""Runs over the simulated world and real data: ``openmulti run`` (``run``), the paper's reproduction
(``reproduce``), open-vocabulary queries of a finished run (``query``) and the command line (``cli``)."""
