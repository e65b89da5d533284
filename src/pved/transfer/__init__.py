"""pved.transfer"""
