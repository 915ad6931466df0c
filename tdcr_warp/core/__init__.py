"""The shooting machinery on the device: device tables built from the model, the batched Newton
driver, homotopies, the CPU thread split, the progress bar and ahead-of-time builds."""
