"""Many cameras: the simulator and launcher around the camera core.

``scenarios/``   what the cameras see: scenario files and presets, the synthetic world, EPFL
                 ground truth, det-files; the ``scenario`` source plug-in of camera processes
``network/``     topologies and the in-process network (and the centralized baseline)
``cluster/``     real clusters of ``edge_node`` processes on loopback (``sim_cluster up``)
``evaluation/``  metrics (py-motmetrics) and the per-node table
``experiments/`` runs (``run_once``), the ablation, the fault report, benchmarks
``viz.py``       Rerun recordings of whole networks; ``progress.py`` progress bars
``cli.py``       the ``sim_cluster`` command line (imported by nobody)
"""
