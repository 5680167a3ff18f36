"""Checks a tracked map's keyframe observations against a rendered sequence's truth (a development tool).

    track_sequence <render> <out.tum> 100000 --dump-map <map.txt>
    python3 observation_truth.py <render> <map.txt> [MODE] [WEIGHTS]

Every point seen in 3+ good keyframes is triangulated with the TRUE keyframe poses from all its observations;
the residuals of its observations are then measurement error, free of pose error. Printed: residual statistics
(by refined/whole-pixel, view-scale change since the first keyframe, octave), each keyframe posed from its
observations of those points, and (MODE other than `depth`) a full bundle adjustment of the observations from
the truth, first keyframe fixed, whose optimum's keyframe centres are compared with the truth (SE(3)-aligned).
MODE: all | refined | whole | clean | cleanobs | depth (points against the rendered surface) | offsets (each point's
later observations against the point its first observation defines) | dropoffset (the same, then the points
off by more than OFFSET px, default 0.4, left out of the adjustment) | synth (every
observation replaced by its true projection + Gaussian noise 0.25·s^octave px) | synth_uv (true left u, v, the
measured disparity kept) | synth_ur (measured left u, v, true disparity) | shuf_all | shuf_kf | shuf_pt (the
left residuals permuted over all observations / within a keyframe / within a point).
WEIGHTS: tracker (refined σ 0.1 of the octave's) | r<σ> (refined σ given) | equal. Env: KER=huber|cauchy|tukey
KC=<width in σ>, INIT=est (start from the tracker's map instead of the truth), PPS=1 (a per-point variance).
Numpy only; about a minute per bundle adjustment on a 400-frame 640×480 render.
"""
import numpy as np, sys, collections
seq, mp = sys.argv[1], sys.argv[2]
fx, fy, cx, cy, bf = 520., 520., 319.5, 239.5, 2600.
import re
for l in open(seq+'/settings.yaml'):
    m = re.match(r'Camera\.(fx|fy|cx|cy|bf): *([-\d.e]+)', l)
    if m: globals()[m.group(1)] = float(m.group(2))
import os
KER=os.environ.get('KER','huber'); KC=float(os.environ.get('KC','2.45'))
def KW(e):
    if KER=='huber': return 1.0 if abs(e)<KC else KC/abs(e)
    if KER=='cauchy': return 1.0/(1.0+(e/KC)**2)
    if KER=='tukey': return (1-(e/KC)**2)**2 if abs(e)<KC else 0.0
    return 1.0
def RS(w):
    return 0.1 if w=='tracker' else (float(w[1:]) if w.startswith('r') else 1.0)
def quat(qx,qy,qz,qw):
    x,y,z,w=qx,qy,qz,qw
    return np.array([[1-2*(y*y+z*z),2*(x*y-z*w),2*(x*z+y*w)],[2*(x*y+z*w),1-2*(x*x+z*z),2*(y*z-x*w)],[2*(x*z-y*w),2*(y*z+x*w),1-2*(x*x+y*y)]])
gt = {}
times=[float(l) for l in open(seq+'/times.txt') if l.strip()]
for l in open(seq+'/gt/poses.tum'):
    if l.startswith('#'): continue
    v=list(map(float,l.split()))
    gt[round(v[0],4)] = (quat(*v[4:8]), np.array(v[1:4]))
first_t = times[0]
def gtpose(t):
    return gt[round(t,4)]
def pfm(path):
    with open(path,'rb') as f:
        f.readline(); w,h=map(int,f.readline().split()); s=float(f.readline())
        d=np.frombuffer(f.read(),dtype='<f4' if s<0 else '>f4').reshape(h,w)
    return d[::-1]
obs = collections.defaultdict(list)
for l in open(mp):
    p=l.split()
    if p[0]=='O':
        obs[int(p[1])].append(dict(pid=int(p[1]),rsd=0.0,kf=int(p[2]),t=float(p[3]),u=float(p[4]),v=float(p[5]),oc=int(p[6]),ur=float(p[7]),ref=int(p[8]),first=int(p[9]),X=np.array(list(map(float,p[10:13])))))
def proj(R,t,X):
    # world_from_camera R,t -> camera coords
    c = R.T@(X-t)
    return c
rows=[]
TRI={}
depth_err=[]
for pid, os_ in obs.items():
    if len(os_)<3: continue
    poses=[gtpose(o['t']) for o in os_]
    # init from first kf obs with its stereo
    o0=[o for o in os_ if o['kf']==o['first']]
    o0 = o0[0] if o0 else os_[0]
    R0,t0=gtpose(o0['t'])
    if o0['ur']<0: continue
    z=bf/(o0['u']-o0['ur']); X=R0@np.array([(o0['u']-cx)*z/fx,(o0['v']-cy)*z/fy,z])+t0
    for it in range(10):
        H=np.zeros((3,3)); g=np.zeros(3)
        for o,(R,t) in zip(os_,poses):
            c=proj(R,t,X); x,y,zc=c
            s=1.2**o['oc']
            r=[o['u']-(fx*x/zc+cx), o['v']-(fy*y/zc+cy)]
            J=[np.array([fx/zc,0,-fx*x/zc**2])@R.T, np.array([0,fy/zc,-fy*y/zc**2])@R.T]
            if o['ur']>=0:
                r.append(o['ur']-(fx*x/zc+cx-bf/zc)); J.append(np.array([fx/zc,0,-fx*x/zc**2+bf/zc**2])@R.T)
            for ri,Ji in zip(r,J):
                H+=np.outer(Ji,Ji)/s**2; g+=Ji*ri/s**2
        dx=np.linalg.solve(H,g); X=X+dx
        if np.linalg.norm(dx)<1e-9: break
    # depth of the surface at first obs
    i = times.index(min(times,key=lambda tt:abs(tt-o0['t'])))+1
    D=pfm(seq+f'/gt/depth/{i}.pfm') if False else None
    c0=proj(R0,t0,X)
    TRI[pid]=X
    for o,(R,t) in zip(os_,poses):
        c=proj(R,t,X); x,y,zc=c
        ru=o['u']-(fx*x/zc+cx); rv=o['v']-(fy*y/zc+cy); rr=(o['ur']-(fx*x/zc+cx-bf/zc)) if o['ur']>=0 else np.nan
        o['rsd']=max(abs(ru),abs(rv),abs(rr) if rr==rr else 0)/(1.2**o['oc'])/0.25
        rows.append((pid,o['kf'],o['kf']-o['first'],zc/c0[2],o['oc'],o['ref'],ru,rv,rr,len(os_),o['kf']==o0['kf'],o['u'],o['v']))
def point_offsets():
    """Per point: its true position is where its first keyframe's observation (the anchor's centre) meets the
    rendered surface (gt/depth of that frame); the mean of its later refined observations' residuals against
    that point, in units of their octave's pixel. Independent errors would make the mean's spread that of the
    residuals over √n; a common offset (the track measuring other tissue than its first observation) does not
    shrink with n."""
    full=[float(l) for l in open(seq.split('-s')[0]+'/times.txt') if l.strip()]
    cache={}; out={}
    for pid,os_ in obs.items():
        if pid not in TRI: continue
        a=[o for o in os_ if o['kf']==o['first']]
        if not a: continue
        a=a[0]; i=min(range(len(full)),key=lambda k:abs(full[k]-a['t']))+1
        if i not in cache: cache[i]=pfm(seq.split('-s')[0]+f'/gt/depth/{i}.pfm')
        D=cache[i]; u,v=a['u'],a['v']; x0,y0=int(u),int(v); ax,ay=u-x0,v-y0
        z=(1-ay)*((1-ax)*D[y0,x0]+ax*D[y0,x0+1])+ay*((1-ax)*D[y0+1,x0]+ax*D[y0+1,x0+1])
        R,t=gtpose(a['t']); X=R@np.array([(u-cx)*z/fx,(v-cy)*z/fy,z])+t
        res=[]
        for o in os_:
            if o is a or not o['ref']: continue
            R,t=gtpose(o['t']); c=R.T@(X-t); sc=1.2**o['oc']
            res.append(((o['u']-(fx*c[0]/c[2]+cx))/sc,(o['v']-(fy*c[1]/c[2]+cy))/sc))
        if len(res)>=2: out[pid]=np.array(res)
    return out
if sys.argv[3] in ('offsets','dropoffset'):
    offs=point_offsets()
    m=np.array([r.mean(0) for r in offs.values()]); n=np.array([len(r) for r in offs.values()])
    w=np.array([((r-r.mean(0))**2).sum(0)/(len(r)-1) for r in offs.values()])
    mad=lambda x:1.4826*np.median(abs(x-np.median(x,0)),0)
    print(f"points {len(m)}, later refined observations per point {n.mean():.1f}")
    print("per-point mean offset u, v: rms", np.sqrt((m**2).mean(0)).round(3), "robust σ", mad(m).round(3),
          "| if independent: rms", np.sqrt((w/n[:,None]).mean(0)).round(3))
    nm=np.linalg.norm(m,axis=1)
    print("points whose later observations are off their first by > 0.25 / 0.4 px: %.3f / %.3f"%((nm>0.25).mean(),(nm>0.4).mean()))
    if sys.argv[3]=='dropoffset':
        limit=float(os.environ.get('OFFSET','0.4'))
        for pid,r in offs.items():
            if np.linalg.norm(r.mean(0))>limit: del TRI[pid]; del obs[pid]
        print(f"left out the points off by > {limit} px")
if sys.argv[3] in ('synth','synthexact','synth_uv','synth_ur'):
    rng=np.random.default_rng(1)
    for pid,os_ in obs.items():
        if pid not in TRI: continue
        for o in os_:
            R,t=gtpose(o['t']); c=R.T@(TRI[pid]-t); sg=1.2**o['oc']*0.25*(sys.argv[3]=='synth')
            nu=fx*c[0]/c[2]+cx+rng.normal()*sg; nv=fy*c[1]/c[2]+cy+rng.normal()*sg; nr=fx*c[0]/c[2]+cx-bf/c[2]+rng.normal()*sg
            if sys.argv[3]=='synth_uv':
                if o['ur']>=0: o['ur']=nu-(o['u']-o['ur'])
                o['u'],o['v']=nu,nv
            elif sys.argv[3]=='synth_ur':
                if o['ur']>=0: o['ur']=o['u']-(nu-nr)
            else:
                o['u'],o['v']=nu,nv
            if sys.argv[3] in ('synth','synthexact') and o['ur']>=0: o['ur']=fx*c[0]/c[2]+cx-bf/c[2]+rng.normal()*sg
if sys.argv[3].startswith('shuf'):
    rng=np.random.default_rng(2)
    allo=[(pid,o) for pid,os_ in obs.items() if pid in TRI for o in os_]
    for pid,o in allo:
        R,t=gtpose(o['t']); c=R.T@(TRI[pid]-t); o['pu']=fx*c[0]/c[2]+cx; o['pv']=fy*c[1]/c[2]+cy
        o['res']=(o['u']-o['pu'],o['v']-o['pv'])
    groups=collections.defaultdict(list)
    for pid,o in allo:
        key={'shuf_all':0,'shuf_kf':o['kf'],'shuf_pt':pid}[sys.argv[3]]
        groups[key].append(o)
    for g in groups.values():
        perm=rng.permutation(len(g)); res=[g[i]['res'] for i in perm]
        for o,(a,b) in zip(g,res):
            d=o['u']-o['ur']
            o['u']=o['pu']+a; o['v']=o['pv']+b
            if o['ur']>=0: o['ur']=o['u']-d
A=np.array(rows,dtype=float)
np.save(mp+'.npy',A)
def rep(name,m):
    a=A[m]
    if len(a)==0: return
    def st(x):
        x=x[~np.isnan(x)]
        return f"mean {x.mean():+.3f} med {np.median(x):+.3f} mad {1.4826*np.median(abs(x-np.median(x))):.3f} rms {np.sqrt((x**2).mean()):.3f}"
    print(f"{name:28s} n={len(a):6d} du {st(a[:,6])} | dv {st(a[:,7])} | dur {st(a[:,8])} | disp(ru-rr) {st(a[:,6]-a[:,8])}")
rep('all',np.ones(len(A),bool))
rep('refined',A[:,5]==1); rep('whole',A[:,5]==0)
rep('anchor(first) obs',A[:,10]==1)
for lo,hi in [(0.5,0.8),(0.8,0.95),(0.95,1.05),(1.05,1.25),(1.25,1.6),(1.6,3)]:
    rep(f'zratio {lo}-{hi} refined',(A[:,3]>=lo)&(A[:,3]<hi)&(A[:,5]==1))
for oc in range(4):
    rep(f'octave {oc} refined',(A[:,4]==oc)&(A[:,5]==1))

# ---- pose noise floor: each keyframe posed from its observations of the truth-triangulated points
def skew(a): return np.array([[0,-a[2],a[1]],[a[2],0,-a[0]],[-a[1],a[0],0]])
def expso3(w):
    th=np.linalg.norm(w)
    if th<1e-12: return np.eye(3)+skew(w)
    k=skew(w/th); return np.eye(3)+np.sin(th)*k+(1-np.cos(th))*k@k
bykf=collections.defaultdict(list)
for pid,os_ in obs.items():
    if pid not in TRI: continue
    for o in os_: bykf[(o['kf'],o['t'])].append((o,TRI[pid]))
est={}
for l in open(mp):
    p=l.split()
    if p[0]=='K': est[int(p[1])]=(quat(*map(float,p[6:10])),np.array(list(map(float,p[3:6]))),float(p[2]))
res=[]
for wmode in ['tracker','equal']:
  errs=[]
  for (kf,t),lst in sorted(bykf.items()):
    R,tt=gtpose(t)
    Rc, tc = R.T, -R.T@tt   # camera_from_world
    for it in range(8):
        H=np.zeros((6,6)); g=np.zeros(6)
        for o,X in lst:
            c=Rc@X+tc; x,y,z=c
            s=1.2**o['oc']*(RS(wmode) if o['ref'] else 1.0)
            Jc=[np.array([fx/z,0,-fx*x/z**2]),np.array([0,fy/z,-fy*y/z**2])]
            r=[o['u']-(fx*x/z+cx),o['v']-(fy*y/z+cy)]
            if o['ur']>=0:
                Jc.append(np.array([fx/z,0,-fx*x/z**2+bf/z**2])); r.append(o['ur']-(fx*x/z+cx-bf/z))
            for ri,j in zip(r,Jc):
                e=ri/s; w=1.0 if abs(e)<2.45 else 2.45/abs(e)   # huber
                J=np.concatenate([j@(-skew(c)), j])  # d c / d (w, v) for left-multiplied increment
                H+=w*np.outer(J,J)/s**2; g+=w*J*ri/s**2
        d=np.linalg.solve(H,g)
        dR=expso3(d[:3]); Rc=dR@Rc; tc=dR@tc+d[3:]
    # camera centre error vs truth
    C=-Rc.T@tc
    errs.append((kf,np.linalg.norm(C-tt)))
  e=np.array(errs)
  print(wmode,"kf centre error from measurements w/ truth points: rms %.4f median %.4f max %.4f"%(np.sqrt((e[:,1]**2).mean()),np.median(e[:,1]),e[:,1].max()))
# estimated keyframe centres vs truth after SE3 alignment
P=[];Q=[]
for kf,(R,t,ts) in est.items():
    P.append(t); Q.append(gtpose(ts)[1])
P=np.array(P);Q=np.array(Q)
mp_,mq=P.mean(0),Q.mean(0)
U,S,Vt=np.linalg.svd((Q-mq).T@(P-mp_)); D=np.eye(3); D[2,2]=np.sign(np.linalg.det(U@Vt))
Ra=U@D@Vt
E=np.linalg.norm((Ra@(P-mp_).T).T+mq-Q,axis=1)
print("estimated kf centres, SE3-aligned: rms %.4f median %.4f max %.4f"%(np.sqrt((E**2).mean()),np.median(E),E.max()))

# ---- full BA from the truth, every keyframe but the first free: where is the optimum of these measurements?
def full_ba(wmode, iters=10, init='truth'):
    kfs=sorted(set(k for k,_ in bykf.keys()))
    tmap={k:t for k,t in bykf.keys()}
    ki={k:i for i,k in enumerate(kfs)}
    poses={}
    for k in kfs:
        if init=='truth':
            R,tt=gtpose(tmap[k]); poses[k]=[R.T,-R.T@tt]
        else:
            R,tt,_=est[k]; poses[k]=[R.T,-R.T@tt]
    pts={pid:TRI[pid].copy() for pid in TRI}
    if init!='truth':
        pts={pid:obs[pid][0]['X'].copy() for pid in TRI}
    fixed=kfs[0]
    for it in range(iters):
        n=len(kfs)*6
        Hcc=np.zeros((n,n)); gc=np.zeros(n)
        blocks={}
        for pid,os_ in obs.items():
            if pid not in pts: continue
            X=pts[pid]
            Hpp=np.zeros((3,3)); gp=np.zeros(3); Hcp={}
            pw=1.0
            if os.environ.get('PPS'):
                ss=[];
                for o in os_:
                    Rc,tc=poses[o['kf']]; c=Rc@X+tc; sg=1.2**o['oc']*(RS(wmode) if o['ref'] else 1.0)
                    ss.append(((o['u']-(fx*c[0]/c[2]+cx))**2+(o['v']-(fy*c[1]/c[2]+cy))**2)/sg**2/2)
                rho=np.median(ss)/0.4549  # median of chi2(1) -> variance factor
                pw=1.0/max(1.0,rho)
            for o in os_:
                if not keep(o): continue
                Rc,tc=poses[o['kf']]; c=Rc@X+tc; x,y,z=c
                s=1.2**o['oc']*(RS(wmode) if o['ref'] else 1.0)
                Jc=[np.array([fx/z,0,-fx*x/z**2]),np.array([0,fy/z,-fy*y/z**2])]
                r=[o['u']-(fx*x/z+cx),o['v']-(fy*y/z+cy)]
                if o['ur']>=0:
                    Jc.append(np.array([fx/z,0,-fx*x/z**2+bf/z**2])); r.append(o['ur']-(fx*x/z+cx-bf/z))
                i=ki[o['kf']]
                for ri,j in zip(r,Jc):
                    e=ri/s; w=pw*KW(e)/s**2
                    Jp=np.concatenate([j@(-skew(c)), j]); Jx=j@Rc
                    if o['kf']!=fixed:
                        Hcc[i*6:i*6+6,i*6:i*6+6]+=w*np.outer(Jp,Jp); gc[i*6:i*6+6]+=w*Jp*ri
                        Hcp[i]=Hcp.get(i,np.zeros((6,3)))+w*np.outer(Jp,Jx)
                    Hpp+=w*np.outer(Jx,Jx); gp+=w*Jx*ri
            Hpp+=np.eye(3)*1e-6
            Hi=np.linalg.inv(Hpp)
            blocks[pid]=(Hi,gp,Hcp)
            for i,B in Hcp.items():
                gc[i*6:i*6+6]-=B@Hi@gp
                for j2,B2 in Hcp.items():
                    Hcc[i*6:i*6+6,j2*6:j2*6+6]-=B@Hi@B2.T
        fi=ki[fixed]; Hcc[fi*6:fi*6+6,fi*6:fi*6+6]+=np.eye(6)*1e12
        dc=np.linalg.solve(Hcc,gc)
        for k in kfs:
            i=ki[k]; d=dc[i*6:i*6+6]
            if k==fixed: continue
            dR=expso3(d[:3]); poses[k]=[dR@poses[k][0],dR@poses[k][1]+d[3:]]
        for pid,(Hi,gp,Hcp) in blocks.items():
            rhs=gp.copy()
            for i,B in Hcp.items(): rhs-=B.T@dc[i*6:i*6+6]
            pts[pid]=pts[pid]+Hi@rhs
    P=np.array([-poses[k][0].T@poses[k][1] for k in kfs]); Q=np.array([gtpose(tmap[k])[1] for k in kfs])
    mp_,mq=P.mean(0),Q.mean(0)
    U,S,Vt=np.linalg.svd((Q-mq).T@(P-mp_)); D=np.eye(3); D[2,2]=np.sign(np.linalg.det(U@Vt)); Ra=U@D@Vt
    sc=np.trace(np.diag(S)@D)/((P-mp_)**2).sum()
    E=np.linalg.norm((Ra@(P-mp_).T).T+mq-Q,axis=1)
    print("sim3 scale %.5f"%sc)
    print(wmode,"full BA from truth, kf centre error: rms %.4f median %.4f max %.4f"%(np.sqrt((E**2).mean()),np.median(E),E.max()))
MODE=sys.argv[3] if len(sys.argv)>3 else 'all'
def keep(o):
    if MODE=='refined': return o['ref']==1 or o['kf']==o['first']
    if MODE=='whole': return o['ref']==0 or o['kf']==o['first']
    if MODE=='oc01': return o['oc']<=1
    if MODE=='clean': return o['pid'] in SURF and abs(SURF[o['pid']])<0.01
    if MODE=='cleanobs': return o['pid'] in SURF and abs(SURF[o['pid']])<0.01 and abs(o['rsd'])<4
    if MODE=='young': return abs(np.log(1.0))<1 and True
    return True
SURF={}
if MODE in ('depth','clean','cleanobs'):
    rel=[];absd=[];oc=[]
    cache={}
    for pid,X in TRI.items():
        o0=[o for o in obs[pid] if o['kf']==o['first']]
        if not o0: continue
        o0=o0[0]; R,t=gtpose(o0['t']); c=R.T@(X-t)
        u=fx*c[0]/c[2]+cx; v=fy*c[1]/c[2]+cy
        i=int(np.argmin([abs(tt-o0['t']) for tt in times]))+1
        if i not in cache: cache[i]=pfm(seq+f'/gt/depth/{i}.pfm')
        D=cache[i]; x0,y0=int(np.floor(u)),int(np.floor(v)); ax,ay=u-x0,v-y0
        if x0<0 or y0<0 or x0+1>=D.shape[1] or y0+1>=D.shape[0]: continue
        d=(D[y0,x0]*(1-ax)*(1-ay)+D[y0,x0+1]*ax*(1-ay)+D[y0+1,x0]*(1-ax)*ay+D[y0+1,x0+1]*ax*ay)
        if not np.isfinite(d): continue
        SURF[pid]=(c[2]-d)/d; rel.append((c[2]-d)/d); absd.append(c[2]-d); oc.append(o0['oc'])
    rel=np.array(rel); oc=np.array(oc)
    print("points %d: depth error of truth-posed triangulation vs surface: rel mean %+.5f median %+.5f mad %.5f; |rel|>1%%: %.3f"%(len(rel),rel.mean(),np.median(rel),1.4826*np.median(abs(rel-np.median(rel))),(abs(rel)>0.01).mean()))
    for k in range(5):
        r=rel[oc==k]
        if len(r): print("  octave",k,len(r),"median %+.5f mean(|r|<1%%) %+.5f"%(np.median(r),r[abs(r)<0.01].mean()))
if MODE!='depth':
    full_ba(sys.argv[4] if len(sys.argv)>4 else 'tracker', init=os.environ.get('INIT','truth'))
