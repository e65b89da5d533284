"""pved.pairing"""
