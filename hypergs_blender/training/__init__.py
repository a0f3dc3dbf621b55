"""Training: data sources (procedural, photos, videos) and their preparation, the trainer, its
optimizer and regularizers, and the export of a checkpoint to the weights the runtime loads."""
