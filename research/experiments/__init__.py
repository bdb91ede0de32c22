"""Experiments on simulated scenes: `data` prepares reviewed scenes, `paper` reproduces the
paper's Tables 7 and 8 (`tracklabel experiment paper`), `finetune` its Table 10 (`tracklabel
experiment finetune`), `default_model` trains the shipped model (`tracklabel experiment
default-model`). Each trains through the product's `pipeline.training.train` with its
`TrainingConfig` defaults; settings are named YAML files in `research/configs`."""
