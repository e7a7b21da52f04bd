"""CNN landslide detection at inference: the paper's patch classifier and our dense model.

Modules: patches (the paper's patch grid and 10 % rule), normalize, models, inference
(patch and dense prediction), detect_stage (the comparison's `detect` stage), registry
(weights + model cards), options (torch-free).

Training, datasets, simulated data, calibration and the benchmark live in
worker/training, which imports this package; this package never imports it (nor the
simulator), so the library stays free of training code.

Importing this package does not import torch; the modules that need it do.
"""
