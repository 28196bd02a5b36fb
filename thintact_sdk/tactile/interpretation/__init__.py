"""Run-time tactile interpretation: image to depth (photometric stereo, Poisson), markers, force and slip."""
