"""The sealed JSON documents: coefficient files, frequency responses, compensator
points, and the sealing and schemas they share."""
