"""The bus library every program shares: protocol, client, keys, atomic files, dataset schemas."""
