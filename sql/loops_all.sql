SELECT loop, pv_tag, op_tag, sp_tag, mv_tag, mode_tag, process_type, unit, span,
       criticality, description, issues
FROM loops
ORDER BY loop
