"""Training of the networks: motion-image data sets, augmentation, input-dropout, the training loop."""
