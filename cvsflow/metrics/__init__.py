"""What an error is and how it is summarised: composed pose errors, their statistics, cluster-robust
covariances.
"""
