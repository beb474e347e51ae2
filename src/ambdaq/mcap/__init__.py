"""The MCAP file format alone: chunks and their one codec contract, the block writer, the
memory-mapped reader and its read plan, schemas, CDR layouts, foreign decoders, the memory
it reads into."""
