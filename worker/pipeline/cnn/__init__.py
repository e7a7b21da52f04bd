"""CNN landslide detection: the paper's patch classifier reproduced, and our dense model.

Modules: patches (dataset creation as the paper), normalize, augment, models,
training (shared) with paper_training (Table 3) and dense_training (ours), inference
(patch and dense prediction), detect_stage (the comparison's `detect` stage), registry
(weights + model cards), evaluation (Tables 6/7) and benchmark, dataset (manifests of
DSM/mask triples), simdata and recon_noise (interim training data from the simulator),
options (torch-free).

Importing this package does not import torch; the modules that need it do.
"""
