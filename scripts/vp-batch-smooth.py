#!/usr/bin/env python3
"""Victoria Park smoothed as a whole: every pose and every tree at once, from the EKF's map.

    scripts/vp-batch-smooth.py RUN_DIR OUT.tum [GATE] [CAUCHY]

RUN_DIR: the outputs of `slam run --data victoria-park:DIR` (its estimates.csv and
map.json). The data folder is SLAM_DATA_DIR/victoria-park or ../shared/datasets/victoria-park.

A check of the question "is the EKF's error on Victoria Park the filter's, or the data's?":
one pose per odometry record (the Ackermann model and the noise of the reader's defaults:
speed 0.5 m/s, steering 3 degrees, range 0.5 m, bearing 1 degree; wheelbase 2.83 m, encoder
offset 0.76 m, laser at 3.78 m / 0.5 m), every tree detection associated once, at the
filter's poses, with the nearest confirmed tree of the run's final map within a Mahalanobis
gate (GATE, default 9.21: chi-square(2) 99 %), then the poses and the trees estimated
together by Gauss-Newton (sparse normal equations; the first pose held; a weak prior,
100 m, on each tree's starting place keeps a tree no detection keeps determined). CAUCHY,
if given, is the scale of a Cauchy loss on each detection's whitened residual. The path
goes to OUT.tum (TUM, at the odometry times); score it with scripts/vp-gps-ate.py.
Needs numpy and scipy.
"""
import csv, json, math, os, sys
import numpy as np, scipy.sparse as sp, scipy.sparse.linalg as spl
from scipy.spatial import cKDTree

if len(sys.argv) < 3:
    sys.exit(__doc__)
run, out = sys.argv[1], sys.argv[2]
GATE = float(sys.argv[3]) if len(sys.argv) > 3 else 9.21
CAUCHY = float(sys.argv[4]) if len(sys.argv) > 4 else None
here = os.path.dirname(os.path.abspath(__file__))
data = os.environ.get("SLAM_DATA_DIR", os.path.join(here, "..", "..", "shared", "datasets"))
D = os.path.join(data, "victoria-park", "converted") + "/"
odo=np.array([[float(r['time_ms'])/1000,float(r['speed_mps']),float(r['steering_rad'])] for r in csv.DictReader(open(D+"odometry.csv"))])
est=np.genfromtxt(f'{run}/estimates.csv',delimiter=',',skip_header=1,usecols=range(10))
L,H,A,B=2.83,0.76,3.78,0.5; SV,SS=0.5,math.radians(3); SR,SB=0.5,math.radians(1)
wrap=lambda a:(a+np.pi)%(2*np.pi)-np.pi
# poses: one per odometry record time (pose after applying that record's motion from the previous time)
T=odo[:,0]; N=len(T)
# initial values: filter estimate at the last estimate time <= T_k
idx=np.searchsorted(est[:,0],T,side='right')-1; idx=idx.clip(0)
X0=est[idx,1:4].copy()
Pcov=np.zeros((N,3,3)); c=est[idx,4:10]
Pcov[:,0,0]=c[:,0];Pcov[:,0,1]=Pcov[:,1,0]=c[:,1];Pcov[:,0,2]=Pcov[:,2,0]=c[:,2];Pcov[:,1,1]=c[:,3];Pcov[:,1,2]=Pcov[:,2,1]=c[:,4];Pcov[:,2,2]=c[:,5]
# motion between pose k-1 and k uses the control of record k-1 over dt = T_k - T_{k-1}
dt=np.diff(T); v=odo[:-1,1]; st=odo[:-1,2]
tan=np.tan(st); den=1-tan*H/L; vc=v/den; om=vc*tan/L
# increments in robot frame and their Jacobian wrt (v, steer)
sec2=1+tan**2
dvc_dv=1/den; dvc_ds=v*(H/L)*sec2/den**2
dom_dv=dvc_dv*tan/L; dom_ds=(dvc_ds*tan+vc*sec2)/L
G=np.zeros((N-1,3,2)); G[:,0,0]=dvc_dv*dt; G[:,0,1]=dvc_ds*dt; G[:,2,0]=dom_dv*dt; G[:,2,1]=dom_ds*dt
Su=np.diag([SV**2,SS**2])
Qr=G@Su@G.transpose(0,2,1)+np.diag([1e-6,1e-6,1e-8])  # floor: 1 mm, 0.1 mrad per record
inc=np.c_[vc*dt,np.zeros(N-1),om*dt]
# trees
m=json.load(open(f'{run}/map.json'))
trees=[(f['feature']['centre'],np.array(f['covariance'])[1:3,1:3]) for f in m['features'] if f['type']=='pole' and f['confirmed']]
TC=np.array([t[0] for t in trees]); TCov=np.array([t[1] for t in trees])
# detections -> pose index (last odometry record <= detection time)
det=[(float(r['time_s']),float(r['range_m']),float(r['bearing_rad'])-math.pi/2) for r in csv.DictReader(open(D+"tree_detections.csv"))]
det=np.array(det); k_of=np.searchsorted(T,det[:,0],side='right')-1; ok=k_of>=0; det=det[ok]; k_of=k_of[ok]
def sensor(X):
    c,s=np.cos(X[:,2]),np.sin(X[:,2]); return np.c_[X[:,0]+A*c-B*s, X[:,1]+A*s+B*c]
def obs_model(X,k,tr):
    x=X[k]; c,s=np.cos(x[:,2]),np.sin(x[:,2]); sx=x[:,0]+A*c-B*s; sy=x[:,1]+A*s+B*c
    dx=TC[tr,0]-sx; dy=TC[tr,1]-sy; q=dx*dx+dy*dy; r=np.sqrt(q)
    pr=np.c_[r, np.arctan2(dy,dx)-x[:,2]]
    dsx=-A*s-B*c; dsy=A*c-B*s
    Jx=np.zeros((len(k),2,3)); Jx[:,0,0]=-dx/r; Jx[:,0,1]=-dy/r; Jx[:,0,2]=-(dx*dsx+dy*dsy)/r
    Jx[:,1,0]=dy/q; Jx[:,1,1]=-dx/q; Jx[:,1,2]=(dy*dsx-dx*dsy)/q-1
    Jt=np.zeros((len(k),2,2)); Jt[:,0,0]=dx/r; Jt[:,0,1]=dy/r; Jt[:,1,0]=-dy/q; Jt[:,1,1]=dx/q
    return pr,Jx,Jt
# association at the initial poses: nearest tree in world within a Mahalanobis gate (pose+tree+meas)
S0=sensor(X0)
wp=S0[k_of]+det[:,1:2]*np.c_[np.cos(X0[k_of,2]+det[:,2]),np.sin(X0[k_of,2]+det[:,2])]
kd=cKDTree(TC); cand=kd.query_ball_point(wp, r=10.0)
tr=-np.ones(len(det),int); best=np.full(len(det),np.inf)
for j in range(len(det)):
    if not cand[j]: continue
    cs=np.array(cand[j]); kk=np.full(len(cs),k_of[j])
    pr,Jx,Jt=obs_model(X0,kk,cs)
    e=np.c_[pr[:,0]-det[j,1],wrap(pr[:,1]-det[j,2])]
    S=Jx@Pcov[kk]@Jx.transpose(0,2,1)+Jt@TCov[cs]@Jt.transpose(0,2,1)+np.diag([SR**2,SB**2])
    d2=np.einsum('ni,nij,nj->n',e,np.linalg.inv(S),e); a=d2.argmin()
    if d2[a]<GATE: tr[j]=cs[a]; best[j]=d2[a]
use=tr>=0; print('detections',len(det),'associated',use.sum())
kO=k_of[use]; tO=tr[use]; zO=det[use,1:3]
def whiten(C):
    Li=np.linalg.inv(np.linalg.cholesky(C)); return Li
def solve(X, it=8, cauchy=None):
    for i in range(it):
        # odometry residuals in world frame
        th=X[:-1,2]; c,s=np.cos(th),np.sin(th)
        R=np.zeros((N-1,3,3)); R[:,0,0]=c;R[:,0,1]=-s;R[:,1,0]=s;R[:,1,1]=c;R[:,2,2]=1
        dw=np.einsum('nij,nj->ni',R,inc)
        pred=X[:-1]+dw; eo=X[1:]-pred; eo[:,2]=wrap(eo[:,2])
        F=np.tile(np.eye(3),(N-1,1,1)); F[:,0,2]=-dw[:,1]; F[:,1,2]=dw[:,0]
        Qw=R@Qr@R.transpose(0,2,1); Wo=whiten(Qw)
        # obs residuals
        pr,Jx,Jt=obs_model(X,kO,tO)
        ez=np.c_[pr[:,0]-zO[:,0],wrap(pr[:,1]-zO[:,1])]
        Sz=np.tile(np.diag([SR**2,SB**2]),(len(kO),1,1)); Wz=whiten(Sz)
        rz=np.einsum('nij,nj->ni',Wz,ez)
        wts=np.ones(len(kO))
        if cauchy: wts=1/(1+(rz**2).sum(1)/cauchy**2)
        sw=np.sqrt(wts)[:,None]
        # build sparse J
        rows=[];cols=[];vals=[]
        # odometry: r = Wo (x_k - f(x_{k-1}))  -> d/dx_k = Wo, d/dx_{k-1} = -Wo F
        Ak=Wo; Bk=-Wo@F
        base=np.arange(N-1)*3
        for a in range(3):
            for b in range(3):
                rows.append(base+a); cols.append(3*(np.arange(N-1)+1)+b); vals.append(Ak[:,a,b])
                rows.append(base+a); cols.append(3*np.arange(N-1)+b); vals.append(Bk[:,a,b])
        ro=np.einsum('nij,nj->ni',Wo,eo).ravel()
        M0=3*(N-1); Jz=(Wz@Jx)*sw[:,:,None]
        bz=M0+np.arange(len(kO))*2
        for a in range(2):
            for b in range(3):
                rows.append(bz+a); cols.append(3*kO+b); vals.append(Jz[:,a,b])
        Jtt=(Wz@Jt)*sw[:,:,None]
        for a in range(2):
            for b in range(2):
                rows.append(bz+a); cols.append(3*N+2*tO+b); vals.append(Jtt[:,a,b])
        # gauge: first pose fixed by a stiff prior
        M1=M0+2*len(kO)
        for a in range(3):
            rows.append(np.array([M1+a])); cols.append(np.array([a])); vals.append(np.array([1e4]))
        nt=len(TC); M2=M1+3
        rows.append(M2+np.arange(2*nt)); cols.append(3*N+np.arange(2*nt)); vals.append(np.full(2*nt,0.01))
        rvec=np.r_[ro,(rz*sw).ravel(),1e4*(X[0]-X00),0.01*(TC-TC0).ravel()]
        J=sp.csr_matrix((np.concatenate(vals),(np.concatenate(rows),np.concatenate(cols))),shape=(M2+2*nt,3*N+2*nt))
        Hm=(J.T@J).tocsc(); g=J.T@rvec
        dx=spl.spsolve(Hm,-g)
        X=X+dx[:3*N].reshape(N,3); X[:,2]=wrap(X[:,2]); TC[:]=TC+dx[3*N:].reshape(-1,2)
        print(' it',i,'cost %.1f'%(rvec@rvec), 'step %.3g'%np.abs(dx).max())
        if np.abs(dx).max()<1e-4: break
    return X
X00=X0[0].copy(); TC0=TC.copy()
Xs=solve(X0.copy(), cauchy=CAUCHY)
# write tum at odometry times
with open(out,'w') as f:
    for t,x in zip(T,Xs): f.write(f"{t:.3f} {x[0]:.6f} {x[1]:.6f} 0 0 0 {math.sin(x[2]/2):.9f} {math.cos(x[2]/2):.9f}\n")
