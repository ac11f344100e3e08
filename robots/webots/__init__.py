"""gridfleet in Webots: the world generator, the PROTO files and the grid unit's controller."""
