"""Experiments: ``run`` (one run plus its evaluation: ``run_once``, ``sim_cluster run``),
``ablation`` (the paper's grid), ``faultreport`` (standard faults against the fault-free run),
``bench`` (core CPU time), ``bench_cluster`` (real clusters), ``bench_perception`` (detectors
and re-id)."""
