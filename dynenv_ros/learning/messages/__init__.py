"""Experience from messages: the trainer node's assembly of per-robot sequences, its learner, and learning from
recorded bags."""
