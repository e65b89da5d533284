"""pved.rl"""
