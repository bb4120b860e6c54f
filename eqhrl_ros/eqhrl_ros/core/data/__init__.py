"""What is stored and what travels: the advice exchange, replay memories D and D_advising, episode
summaries, transition batches, weights, signed messages and torch's files. Imports no other wing."""
