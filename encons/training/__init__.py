"""Training: the LightningModule and its objectives, the attempt policy, callbacks, the builders (checked config
-> objects), fitting with stops and resumes, single runs and ensembles of seeds (stacked or looped)."""
