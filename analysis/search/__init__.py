"""Model discovery: the law sets of an element that has none, screened on its kbar and judged on the FRFs
(``discovery``, the front end and the method's overview; docs/discovery.md). Along the method's path:
``records`` (the rules and what discovery returns), ``candidates`` (the sets fitted to each kbar),
``kbar_evidence`` (what the kbar shows of them), ``frf_judge`` (the FRFs' verdict), ``walk`` (the walk and the
choice); each imports only those before it.

May import: every room before it: ``common`` to ``missing``.
"""
