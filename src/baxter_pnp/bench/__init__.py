"""Benchmarks and experiments on top of everything: batch trials and the soak (``trials``, ``trial_scenes``,
``soak``, ``ground_truth``, ``records``), the thesis's experiments (``experiments``), the perception benchmark
(``perception_bench``) and the demos (``demo``, ``perception_demo``). They may read the fake Baxter's ground
truth; the application never does. Import the submodules explicitly."""
