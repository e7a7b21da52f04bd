"""Training of the detection models, outside the library (worker/pipeline).

Modules: dataset (manifests of DSM/mask triples), augment, training (shared) with
paper_training (Table 3) and dense_training (ours), trainer (the one entry point of
`slidewatch train` and the training task), calibration (fitting a card's min_score),
evaluation (Tables 6/7) and benchmark, simdata, recon_noise and reconstructed_data
(training data from the survey simulator).

Training depends on the library (worker/pipeline/cnn: models, normalisation, patches,
inference, registry) and on the simulator; the library depends on neither, which is why
this code is a package of its own: worker.pipeline <-> worker.simulator would otherwise
be a cycle.

Importing this package does not import torch or the simulator; the modules that need
them do.
"""
