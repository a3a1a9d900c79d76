"""Training of the networks: motion-image data sets, augmentation, input-dropout, the shared training loop
(:mod:`.base`), the EpO motion net (:mod:`.trainer`) and the EpO+ fusion (:mod:`.fusion`)."""
