"""Measurement, kept out of the algorithm: speed benchmark (:mod:`.speed`), flow accuracy on
Middlebury and the synthetic ball (:mod:`.flow_accuracy`), fusion quality against ground truth
(:mod:`.quality`) and the built-in demo (:mod:`.demo`). The CLI's ``bench``, ``bench-flow``
and ``demo`` commands are thin faces of these modules; scoring itself is
:func:`fuse4d.metrics.evaluate`.
"""
