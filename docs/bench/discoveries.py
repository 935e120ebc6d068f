"""Per-seed figures of a `qfleet sweep --robots 4 --sharing hints,both` (docs/fleet.md,
"Discoveries of the planning learner"): for every map, per sharing mode, the median over the 4
robots of the env steps to the robot's own optimum, per seed, summarised over the seeds, and
the per-seed ratio both / hints. Usage: python3 docs/bench/discoveries.py results/disc-heldout
"""
import json,glob,os,statistics as st,sys
root=sys.argv[1]
for m in sorted(glob.glob(root+'/*/')):
    rows={}
    for d in sorted(glob.glob(m+'n4-*')):
        tag=os.path.basename(d); mode=tag.split('-')[1]; seed=int(tag.split('-s')[-1])
        try: r=json.load(open(d+'/result.json'))
        except Exception: continue
        rb=r['phases'][0]['robots']
        steps=[x['steps_to_optimal'] for x in rb if x['steps_to_optimal'] is not None]
        times=[x['time_to_optimal_s'] for x in rb if x.get('time_to_optimal_s') is not None]
        med=st.median(steps) if len(steps)==len(rb) else float('inf')
        rows.setdefault(mode,{})[seed]=(med, st.median(times) if times else None, sum(x['relays_applied'] for x in rb), len(steps), len(rb), r.get('wall_s'))
    print(os.path.basename(m.rstrip('/')))
    for mode,v in rows.items():
        meds=[x[0] for x in v.values()]; ts=[x[1] for x in v.values() if x[1]]
        print(f"  {mode:6} runs {len(v)} median-of-seed-medians {st.median(meds):9.0f} mean {st.mean(meds):9.0f} sd {st.pstdev(meds):7.0f} min {min(meds):7.0f} max {max(meds):7.0f}  time-to-opt median {st.median(ts):.3f}s  relays applied/run {st.mean([x[2] for x in v.values()]):.1f} optimal {sum(x[3] for x in v.values())}/{sum(x[4] for x in v.values())}")
    if 'hints' in rows and 'both' in rows:
        common=sorted(set(rows['hints'])&set(rows['both']))
        ratios=[rows['both'][s][0]/rows['hints'][s][0] for s in common]
        print(f"  per-seed ratio both/hints: median {st.median(ratios):.3f} min {min(ratios):.3f} max {max(ratios):.3f}")
