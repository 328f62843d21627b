"""Record every bus message to MCAP and replay recordings onto the bus."""
