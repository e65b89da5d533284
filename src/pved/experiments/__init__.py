"""pved.experiments"""
