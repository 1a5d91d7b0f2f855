"""Ground truth for tests and benchmarks: simulated recordings and images.

Holds the sequence simulator: motions, scenes, tracks with noise and outliers
(:mod:`~apcc_graph.simulation.simulator`, its motions in :mod:`~apcc_graph.simulation.motion`, its
faults in :mod:`~apcc_graph.simulation.faults`), the same generated frame by frame for streams of
any length (:mod:`~apcc_graph.simulation.stream`), the renderer of what each tip camera sees
(:mod:`~apcc_graph.simulation.render`), rendered calibration photos
(:mod:`~apcc_graph.simulation.calibration_photos`, with the marker drawing in
:mod:`~apcc_graph.simulation.marker_drawing`) and rods that are not APCC, to test the
calibration on (:mod:`~apcc_graph.simulation.planar_curves`).

May import: :mod:`apcc_graph.model`, :mod:`apcc_graph.io`, :mod:`apcc_graph.frontend` and
:mod:`apcc_graph.calibration` (the photo renderer draws the markers the calibration detects).
"""
