"""What a user solves, composed of core pieces: sensitivities, stability, statics, dynamics."""
